"""The command line the two minimal MLS-MPM steps share (taichi_mlsmpm.py, numba_mlsmpm.py)."""

from __future__ import annotations

import argparse
import json


def command_line(measure, language: str, argv=None) -> int:
    """Parse ``--particles --steps --repeats --threads --json``, run ``measure`` with them and
    print one line, or one JSON object (the last line of stdout, which callers read)."""
    parser = argparse.ArgumentParser(description=f"a minimal MLS-MPM step in {language}")
    for name, default in (("particles", 160_000), ("steps", 50), ("repeats", 5), ("threads", 2)):
        parser.add_argument(f"--{name}", type=int, default=default)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    r = measure(args.particles, args.steps, args.repeats, args.threads)
    print(json.dumps(r) if args.json else
          f"{language} MLS-MPM, {r['particles']} particles, {r['threads']} threads: "
          f"{r['step_s'] * 1e3:.2f} ms/step, {r['particle_updates_per_s']:.3g} updates/s")
    return 0
