# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""The template folder rule with symlinks: a geometry file must resolve inside the YAML's folder,
or inside the folder of the YAML's real file (a ``colcon build --symlink-install`` share folder
links every file on its own); anything resolving elsewhere stays refused unless the template
says ``allow_external_files: true``."""

import shutil
from pathlib import Path

import pytest

from affordance_registration.core.errors import AffordanceError
from affordance_registration.core.templates import TemplateLibrary, default_models_dir

MODELS = Path(default_models_dir())


def _src(tmp_path) -> Path:
    """A copy of the ball valve template: YAML and meshes."""
    src = tmp_path / "src"
    (src / "meshes").mkdir(parents=True)
    shutil.copy(MODELS / "ball_valve.yaml", src)
    for mesh in (MODELS / "meshes").glob("ball_valve*"):
        shutil.copy(mesh, src / "meshes")
    return src


def _link_tree(src: Path, dst: Path) -> None:
    """Real folders, every file a symlink to its source (what --symlink-install makes)."""
    for path in src.rglob("*"):
        target = dst / path.relative_to(src)
        if path.is_dir():
            target.mkdir(parents=True, exist_ok=True)
        else:
            target.parent.mkdir(parents=True, exist_ok=True)
            target.symlink_to(path)


def test_a_folder_of_links_loads_like_the_real_one(tmp_path):
    src = _src(tmp_path)
    _link_tree(src, tmp_path / "share")
    assert (tmp_path / "share" / "meshes" / "ball_valve.stl").is_symlink()
    real = TemplateLibrary.load(str(src))["ball_valve"]
    linked = TemplateLibrary.load(str(tmp_path / "share"))["ball_valve"]
    assert linked.mesh.vertices.shape == real.mesh.vertices.shape
    assert (linked.mesh.vertices == real.mesh.vertices).all()


def test_a_link_inside_the_folder_to_a_file_inside_it_is_followed(tmp_path):
    src = _src(tmp_path)
    (src / "meshes" / "alias.stl").symlink_to(src / "meshes" / "ball_valve.stl")
    text = (src / "ball_valve.yaml").read_text()
    (src / "ball_valve.yaml").write_text(
        text.replace("mesh: meshes/ball_valve.stl", "mesh: meshes/alias.stl")
    )
    assert "ball_valve" in TemplateLibrary.load(str(src))


@pytest.mark.parametrize("linked_yaml", [False, True])
def test_a_link_resolving_outside_both_folders_is_refused(tmp_path, linked_yaml):
    src = _src(tmp_path)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    shutil.move(src / "meshes" / "ball_valve.stl", elsewhere / "ball_valve.stl")
    (src / "meshes" / "ball_valve.stl").symlink_to(elsewhere / "ball_valve.stl")
    folder = src
    if linked_yaml:
        folder = tmp_path / "share"
        _link_tree(src, folder)
    with pytest.raises(AffordanceError, match="outside the template's folder"):
        TemplateLibrary.load(str(folder))
    # the template may opt out
    yaml_file = src / "ball_valve.yaml"
    yaml_file.write_text(yaml_file.read_text() + "allow_external_files: true\n")
    assert "ball_valve" in TemplateLibrary.load(str(folder))
