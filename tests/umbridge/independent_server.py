"""An independent UM-Bridge server for the tests: the umbridge package's own ``serve_models``
with two analytic models written here, not in uqflow.

    python independent_server.py PORT

"ishigami": Y = sin x1 + a sin² x2 + b x3⁴ sin x1 (a = 7, b = 0.1), one input vector of 3;
``config["delay"]`` s of sleep per call, an exception above ``config["raise_above"]`` (x3).
"decay": y' = -k y, y(0) = 1, by explicit Euler on [0, 1]; ``config["level"]`` = l takes
2^(l + 2) steps; outputs y(1) and the path at 5 equally spaced times (linear interpolation).
"""

import math
import sys
import time

import numpy as np
import umbridge


class FixedSizes(umbridge.Model):
    """A model whose input and output sizes do not depend on the config."""

    def __init__(self, name, inputs, outputs):
        super().__init__(name)
        self.inputs, self.outputs = inputs, outputs

    def get_input_sizes(self, config):
        return self.inputs

    def get_output_sizes(self, config):
        return self.outputs

    def supports_evaluate(self):
        return True


class Ishigami(FixedSizes):
    def __init__(self):
        super().__init__("ishigami", [3], [1])

    def __call__(self, parameters, config):
        time.sleep(config.get("delay", 0.0))      # a slower model, to be killed mid-study
        x1, x2, x3 = parameters[0]
        if x3 > config.get("raise_above", math.inf):
            raise ValueError(f"x3 = {x3} is out of this model's range")
        return [[math.sin(x1) + 7.0 * math.sin(x2) ** 2 + 0.1 * x3**4 * math.sin(x1)]]


class Decay(FixedSizes):
    def __init__(self):
        super().__init__("decay", [1], [1, 5])

    def __call__(self, parameters, config):
        k = parameters[0][0]
        steps = 2 ** (int(config.get("level", 2)) + 2)
        y = [1.0]
        for _ in range(steps):
            y.append(y[-1] * (1.0 - k / steps))
        path = np.interp(np.linspace(0.0, 1.0, 5), np.linspace(0.0, 1.0, steps + 1), y)
        return [[y[-1]], path.tolist()]


if __name__ == "__main__":
    umbridge.serve_models([Ishigami(), Decay()], port=int(sys.argv[1]))
