"""Upper bounds on every input, so that a typo cannot hang feltool, overflow a float or ask for
more memory than the machine has.

The numbers are far above what a real experiment needs (the thesis runs 100 Hz, 1 s periods,
10 basis functions, alpha_z = 25, 20 seeds) and low enough that nothing overflows or allocates
without bound; the schema (:mod:`feltool.config`) states each one in its field's description,
and ``docs/configuration.md`` lists them.
"""

from __future__ import annotations

from collections import Counter

from feltool.errors import InputError

# -- the YAML file -------------------------------------------------------------------------------
#: Largest config file in [bytes] (a config is a few kB; a sweep grid a few more).
MAX_CONFIG_BYTES = 1 << 20
#: Largest URDF file in [bytes] (the biggest of example-robot-data has 0.2 MB).
MAX_URDF_BYTES = 32 << 20
#: Most links of a URDF (humanoids with hands have about 100; thousands of links in a chain
#: overflow the recursion of the URDF parser behind Pinocchio).
MAX_URDF_LINKS = 1000
#: Deepest nesting of mappings and lists (a config nests about 5 deep).
MAX_YAML_DEPTH = 40
#: Most values after expanding aliases (``*name``): an "alias bomb" expands a few lines into
#: billions of values.
MAX_YAML_NODES = 100_000

# -- numbers of the schema -----------------------------------------------------------------------
MAX_RATE_HZ = 100_000.0     # control rate [Hz]
MAX_PERIOD_S = 3600.0       # period of the rhythmic motion [s]
MAX_STEPS_PER_CYCLE = 1_000_000  # period_s * rate_hz
MAX_CYCLES = 10_000_000     # learning cycles (also an event's cycle)
MAX_ALPHA = 10_000.0        # alpha_z, beta_z [-]
MAX_WIDTH = 10_000.0        # von Mises width h [-]
MAX_AMPLITUDE = 1.0e6       # amplitude factor r [-]
MAX_GAIN = 1.0e8            # kp [N m/rad], kd [N m s/rad]
MAX_RATE = 1.0e6            # learning rates
MAX_SEEDS = 100_000         # seeds of one run
MAX_SEED = 2**63 - 1        # a seed value (int64, as metrics.csv stores it)
MAX_ABS_GRAVITY = 1000.0    # each gravity component [m/s^2] (about 100 g)
MAX_SWEEP_POINTS = 10_000   # points of a sweep grid
MAX_HARMONICS = 50          # higher harmonics of a sine demo
MAX_ANGLE = 1.0e4           # angles and positions of demos, targets, postures [rad] or [m]
MAX_LENGTH = 1.0e3          # centre-of-mass offsets [m]
MAX_MASS = 1.0e6            # masses of plant overrides, payloads, events [kg]
MAX_MASS_SCALE = 1.0e6      # plant.bodies.*.mass_scale [-]
MAX_LENGTH_SCALE = 100.0    # plant.bodies.*.length_scale [-]
MAX_WEIGHT_SCALE = 100.0    # learn.weight_scale [-]
MAX_DAMPING = 1.0e6         # Levenberg-Marquardt damping [-]

#: Fraction of the available memory a planned run may use (see :mod:`feltool.config.memory`).
MEMORY_FRACTION = 0.8


def parse_seeds(spec: str) -> list[int]:
    """``0-19`` | ``0,3,7`` | ``5`` (a single seed) -> a sorted list of distinct seeds, at most
    :data:`MAX_SEEDS` of them (counted before any list is built)."""
    ranges: list[tuple[int, int]] = []
    try:
        for part in spec.split(","):
            part = part.strip()
            lo, hi = (int(x) for x in part.split("-", 1)) if "-" in part else (int(part),) * 2
            if hi < lo or lo < 0:
                raise ValueError
            ranges.append((lo, hi))
    except ValueError:
        raise InputError(f"--seeds: cannot read '{spec}'; use e.g. 0-19, 0,3,7 or 5") from None
    count = sum(hi - lo + 1 for lo, hi in ranges)
    if count > MAX_SEEDS:
        raise InputError(f"--seeds: '{spec}' is {count} seeds; at most {MAX_SEEDS} per run")
    if max(hi for _, hi in ranges) > MAX_SEED:
        raise InputError(f"--seeds: a seed may be at most {MAX_SEED} (2^63 - 1)")
    seeds = [s for lo, hi in ranges for s in range(lo, hi + 1)]
    repeated = sorted(s for s, n in Counter(seeds).items() if n > 1)
    if repeated:
        raise InputError(f"--seeds: seed {', '.join(map(str, repeated[:10]))} given more than "
                         f"once in '{spec}'; each seed runs once")
    return sorted(seeds)


def whole_number(value, name: str, lo: int, hi: int) -> int:
    """``value`` as an int if it is a whole number in ``[lo, hi]`` (an int or a numpy
    integer; not a bool, a float or a string), else an :class:`InputError` naming ``name``:
    the public API's arguments meet the bounds the command line and the config meet."""
    import numbers

    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise InputError(f"{name}: must be a whole number, got {value!r} "
                         f"({type(value).__name__})")
    if not lo <= int(value) <= hi:
        raise InputError(f"{name}: must be from {lo} to {hi}, got {int(value)}")
    return int(value)


def check_cycles(value, name: str = "cycles") -> int:
    """A number of learning cycles: 1 to :data:`MAX_CYCLES`."""
    return whole_number(value, name, 1, MAX_CYCLES)


def check_seed(value, name: str = "seed") -> int:
    """A seed: 0 to :data:`MAX_SEED` (the bounds of ``--seeds`` and the config's ``seeds``)."""
    return whole_number(value, name, 0, MAX_SEED)
