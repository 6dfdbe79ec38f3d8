# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The stages of a fit, one module each, in the order the recipe (:mod:`..registrar`) runs
them; each stage is a function of the click's :class:`~..state.FitState` that returns the next
one, and reads the settings group named after it.

prepare (``crop``: the click snapped, the crop around it), hypothesise (``hypotheses``: where
ICP starts), coarse (``coarse``: every restart on few samples), prefilter (``prefilter``: the
templates clearly worse leave), medium (``medium``: the best distinct few per template), rank
(each template's best), articulate (``articulation``: joint value and scale of the leaders),
finish (``finish``, ``fine``: the leaders' yaw sweep and fine stage), judge (``verdict``: does
it fit), primitives (boxes and cylinders measured), assess (``viewpoint``: is the answer
settled); paper (the literal method, in place of hypothesise ... judge with ``method: paper``)
and refit (an operator's correction refitted, ``refit``).
"""
