"""Particle snapshots of an MPM run as legacy VTK files for ParaView (scene key ``snapshots``;
docs/mpm_scenes.md, "Particle snapshots (VTK)").

One file per snapshot time, ``<directory>/<run tag>/particles_<frame:05d>.vtk``: legacy VTK,
binary (big-endian, as the legacy format requires), POLYDATA with one VERTEX cell per particle
(z = 0), the particle fields as POINT_DATA (positions double, fields float32, material / body
index int32). Next to them:

* ``particles.vtk.series``: ParaView's JSON file-series meta file (ParaView >= 5.5) listing
  each file with its time, so the series opens with the physical times. (A ``.pvd`` collection
  cannot be used: ParaView's PVD reader only reads the XML formats .vtp/.vtu/..., not legacy
  .vtk.) Rewritten after every frame, so a run that fails part-way leaves a valid series.
* ``run.json``: the run tag, the parameters of the realization, material labels and body
  names in index order (the ``material`` / ``body`` fields are indices into these), times.

The run tag identifies the realization: ``nominal`` without parameters, else the first 12 hex
digits of the sha256 of the sorted (name, value) pairs — a repeated or resumed study writes
to the same place, different realizations never collide. Every file is written to a temporary
name and moved into place (``os.replace``), so a reader never sees half a file.

Snapshots are taken at output index k when k is a multiple of ``interval / output_interval``
(k = 0, the initial state, included): exactly the states the probes record.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from collections.abc import Mapping

import numpy as np

from solvers.mpm.probes import probe_values
from uqflow.errors import SceneError

TAG_HEX = 12
NOMINAL_TAG = "nominal"
SERIES_NAME = "particles.vtk.series"
RUN_INFO_NAME = "run.json"


def run_tag(params: Mapping[str, float] | None) -> str:
    """``nominal`` for no parameters, else the first 12 hex digits of the sha256 of the
    sorted (name, float value) pairs (JSON, exact float repr)."""
    if not params:
        return NOMINAL_TAG
    items = sorted((str(k), float(v)) for k, v in params.items())
    text = json.dumps(items, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:TAG_HEX]


def _atomic_write(path: str, data: bytes):
    tmp = os.path.join(os.path.dirname(path), f".{os.path.basename(path)}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


def vtk_bytes(x, y, fields, title="uqflow mpm particles"):
    """A legacy binary VTK POLYDATA file (bytes): one VERTEX per point (x, y, 0).

    ``fields``: sequence of (name, array) — an (n,) float array is a SCALARS float, an (n,)
    integer array a SCALARS int, an (n, 3) array a VECTORS float.
    """
    n = int(np.size(x))
    title = " ".join(str(title).split())[:255]
    pts = np.zeros((n, 3), dtype=">f8")
    pts[:, 0] = x
    pts[:, 1] = y
    verts = np.empty((n, 2), dtype=">i4")
    verts[:, 0] = 1
    verts[:, 1] = np.arange(n)
    out = [f"# vtk DataFile Version 3.0\n{title}\nBINARY\nDATASET POLYDATA\n"
           f"POINTS {n} double\n".encode(), pts.tobytes(),
           f"\nVERTICES {n} {2 * n}\n".encode(), verts.tobytes(),
           f"\nPOINT_DATA {n}\n".encode()]
    for name, a in fields:
        a = np.asarray(a)
        if a.ndim == 2:
            out += [f"VECTORS {name} float\n".encode(), a.astype(">f4").tobytes(), b"\n"]
        elif np.issubdtype(a.dtype, np.integer):
            out += [f"SCALARS {name} int 1\nLOOKUP_TABLE default\n".encode(),
                    a.astype(">i4").tobytes(), b"\n"]
        else:
            out += [f"SCALARS {name} float 1\nLOOKUP_TABLE default\n".encode(),
                    a.astype(">f4").tobytes(), b"\n"]
    return b"".join(out)


def particle_fields(names, run):
    """(name, array) of each snapshot field of the run's current state."""
    parts = run.solver.parts
    out = []
    for name in names:
        if name == "velocity":
            v = np.zeros((run.x.size, 3))
            v[:, 0] = run.vx
            v[:, 1] = run.vy
            out.append((name, v))
        elif name == "material":
            out.append((name, np.asarray(parts.material, dtype=np.int32)))
        elif name == "body":
            out.append((name, np.asarray(parts.body, dtype=np.int32)))
        else:
            out.append((name, probe_values(name, run.S, run.vx, run.vy, run.x, run.y,
                                           run.cfg.conventions)))
    return out


class SnapshotWriter:
    """Writes the particle snapshots of one run (``cfg.snapshots``) for the parameters
    ``params`` of the realization (they name the run's directory, ``run_tag``)."""

    def __init__(self, cfg, params: Mapping[str, float] | None = None):
        sn = cfg.snapshots
        if sn is None:
            raise ValueError("the scene has no snapshots table")
        self.cfg = cfg
        self.spec = sn
        self.params = {str(k): float(v) for k, v in dict(params or {}).items()}
        self.tag = run_tag(self.params)
        self.path = os.path.join(sn.directory, self.tag)
        try:
            os.makedirs(self.path, exist_ok=True)
        except OSError as exc:
            raise SceneError(f"cannot create {self.path}: {exc.strerror or exc}",
                             key="scene.snapshots.directory") from None
        self.frames = []              # (file name, time)
        self.write_seconds = 0.0
        self.bytes_written = 0
        self._write_info()

    @classmethod
    def open(cls, cfg, params=None) -> "SnapshotWriter | None":
        """The writer of a run, or None when the scene has no ``snapshots`` table."""
        return cls(cfg, params) if cfg.snapshots is not None else None

    def _write_info(self):
        info = {"tag": self.tag, "parameters": self.params,
                "materials": list(self.cfg.materials), "bodies": [b.name for b in self.cfg.bodies],
                "fields": list(self.spec.fields), "interval": self.spec.interval,
                "frames": [{"file": f, "time": t} for f, t in self.frames]}
        _atomic_write(os.path.join(self.path, RUN_INFO_NAME),
                      (json.dumps(info, indent=1) + "\n").encode())

    def _write_series(self):
        doc = {"file-series-version": "1.0",
               "files": [{"name": f, "time": t} for f, t in self.frames]}
        _atomic_write(os.path.join(self.path, SERIES_NAME),
                      (json.dumps(doc, indent=1) + "\n").encode())

    def maybe_write(self, k: int, run) -> bool:
        """Write the snapshot of output index ``k`` if it falls on the interval."""
        if k % self.spec.every:
            return False
        t0 = time.perf_counter()
        frame = k // self.spec.every
        t = float(run.solver.times[k])
        name = f"particles_{frame:05d}.vtk"
        data = vtk_bytes(run.x, run.y, particle_fields(self.spec.fields, run),
                         title=f"uqflow mpm particles t = {t!r} s run {self.tag}")
        _atomic_write(os.path.join(self.path, name), data)
        self.frames.append((name, t))
        self._write_series()
        self.bytes_written += len(data)
        self.write_seconds += time.perf_counter() - t0
        return True

    def close(self):
        """Finish the series and run.json (also after a failed run: the frames so far)."""
        self._write_series()
        self._write_info()
