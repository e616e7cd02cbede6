"""A one-line console progress bar: realizations done, failures, ETA."""

from __future__ import annotations

import sys
import time


class Progress:
    def __init__(self, total: int, done: int = 0, enabled: bool = True, stream=None):
        self.total, self.done, self.failed = total, done, 0
        self.start_done = done
        self.stream = stream or sys.stderr
        self.enabled = enabled and total > 0
        self.tty = self.enabled and self.stream.isatty()
        self.start = time.monotonic()
        self.last_line = -1.0
        self._draw()

    def update(self, n: int, failed: int) -> None:
        self.done += n
        self.failed += failed
        self._draw()

    def _draw(self, final: bool = False) -> None:
        if not self.enabled:
            return
        frac = self.done / self.total
        elapsed = time.monotonic() - self.start
        ran = self.done - self.start_done
        eta = elapsed / ran * (self.total - self.done) if ran else float("nan")
        width = 30
        bar = "#" * int(frac * width) + "-" * (width - int(frac * width))
        eta_text = "" if final or eta != eta else f", ETA {eta:.0f} s"
        text = (f"[{bar}] {self.done}/{self.total} realizations, {self.failed} failed"
                f"{eta_text}" + (f", {elapsed:.1f} s" if final else ""))
        if self.tty:
            self.stream.write("\r" + text + " " * 8 + ("\n" if final else ""))
            self.stream.flush()
        elif final or (frac - self.last_line >= 0.25 and self.done < self.total):
            # Not a terminal (CI, a log file): a few lines, not thousands of carriage returns.
            self.stream.write(text + "\n")
            self.last_line = frac

    def close(self) -> None:
        self._draw(final=True)
