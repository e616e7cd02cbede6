"""Probe names become parts of file names (the report's figures ``mpm_<output>_<probe>.png``):
a scene whose probe name could leave the figures folder, make a subfolder or a hidden file is
refused at load, one line naming the key."""

from __future__ import annotations

import pytest

from solvers.mpm.scene import parse
from uqflow.errors import SceneError

from .test_local_sensitivities import small_scene


@pytest.mark.parametrize("name", ["../../../escaped", "G/K", "a\\b", ".hidden", "..", ".",
                                  "H I", "S:11", "probe\n", "Ä"])
def test_probe_names_that_cannot_name_files_are_refused(name):
    sc = small_scene()
    sc["probes"][1]["name"] = name
    with pytest.raises(SceneError) as e:
        parse(sc)
    assert e.value.key == "scene.probes[1].name"
    assert "\n" not in str(e.value).replace(repr(name), "")


@pytest.mark.parametrize("name", ["Q", "x9mm", "probe-1.a", "A_b.c-9"])
def test_file_safe_probe_names_are_kept(name):
    sc = small_scene()
    sc["probes"][1]["name"] = name
    assert parse(sc).probes[1].name == name
