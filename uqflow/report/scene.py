"""The scene a result ran, rebuilt from its provenance for a solver's report (a scene map)."""

from __future__ import annotations

import copy
import hashlib
import json
import os
import tomllib
from collections.abc import Mapping
from pathlib import Path

from uqflow.errors import StudyError
from uqflow.layout import STUDY_OVERRIDES, STUDY_READ_FILES, STUDY_TEXT
from uqflow.overrides import read_overrides, set_key

SCENE = "scene"


def scene_ran(attrs: Mapping) -> tuple[dict | None, str]:
    """The scene a result ran, as a table, and where it came from; (None, why) when it cannot
    be had. The stored study text's inline scene table; else the scene file the study read,
    while it still holds the text the study read (its sha256 in ``study_read_files``); the
    command line's overrides of scene keys (``study_overrides``) applied on top, as ``--set``
    applied them."""
    try:
        study = tomllib.loads(str(attrs.get(STUDY_TEXT) or ""))
    except tomllib.TOMLDecodeError:
        study = {}
    scene, where = study.get(SCENE), "the study's inline scene table"
    if not isinstance(scene, dict):
        read = json.loads(str(attrs.get(STUDY_READ_FILES) or "{}"))
        if SCENE not in read:
            return None, "the result names no scene file and stores no scene table"
        path, sha = read[SCENE]
        try:
            text = Path(path).read_text(encoding="utf-8-sig")
        except (OSError, UnicodeDecodeError):
            return None, f"the scene file {path} cannot be read from here"
        if hashlib.sha256(text.encode()).hexdigest() != sha:
            return None, f"the scene file {path} changed after the run (sha256 differs)"
        try:
            scene = tomllib.loads(text)
        except tomllib.TOMLDecodeError:
            return None, f"the scene file {path} is not valid TOML"
        where = f"the scene file {os.path.normpath(path)}"
    scene = copy.deepcopy(scene)
    try:
        for key, value in read_overrides(str(attrs.get(STUDY_OVERRIDES) or "")).items():
            if key.startswith(f"{SCENE}."):
                set_key(scene, key.removeprefix(f"{SCENE}."), value)
    except StudyError as exc:
        return None, f"the recorded override cannot be applied: {exc.reason}"
    return scene, where
