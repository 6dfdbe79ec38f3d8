# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The ROS-free core: templates, scenes, registration, the engine, corrections and simulation.

Nothing under ``affordance_registration.core`` imports rclpy or any ROS message package.
"""

from .errors import AffordanceError, RegistrationError, SceneError, TemplateError

__all__ = ["AffordanceError", "RegistrationError", "SceneError", "TemplateError"]
