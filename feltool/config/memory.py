"""Memory a planned run needs, estimated before anything big is allocated.

A learning cycle holds arrays over all n = period_s * rate_hz samples of the cycle: each joint's
RMP keeps its discretisation (Gauss-Legendre rows while it is built, then Gamma, the limit-cycle
matrices Xq, Xv, Xa: about 20 numbers per sample and parameter), the learner's Jacobian
d u_ff / d theta is n x nv x P_learned (with its temporaries about 6 copies), the inverse
model's derivatives n x nv x nv (about 4), the cycle's log and recorded traces about 30 numbers
per sample and joint, and model learning's features n x nv x P_model (about 3 copies); and
every cycle keeps a row of metrics (about 1 kB); the compiled engine adds its cycle data and its
functions' work arrays. The estimate is an upper bound of these
(measured against the peak resident size in tests/test_physical.py); :func:`check_memory`
refuses a run whose processes would need more than :data:`~feltool.bounds.MEMORY_FRACTION` of
the memory available.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

from feltool.bounds import MEMORY_FRACTION
from feltool.errors import ConfigError

if TYPE_CHECKING:
    from feltool.config.experiment import ExperimentConfig

_FLOAT = 8  # bytes


def estimate_bytes(cfg: ExperimentConfig, joints: list[str], n_bodies: int) -> int:
    """Peak bytes of one process running one seed of ``cfg`` on a model whose moving joints
    are ``joints`` (after locking) with ``n_bodies`` bodies."""
    n, nv = cfg.steps_per_cycle, len(joints)
    params, learned = 0, 0
    for name in joints:
        jc = cfg.joints.get(name)
        if jc is None:
            continue
        basis = cfg.primitives.basis
        if jc.primitive is not None and jc.primitive.basis is not None:
            basis = jc.primitive.basis
        params += basis + 1
        learned += (basis + 1) if jc.learn is not None else 0
    model = 0
    if cfg.learning.model is not None:
        m = cfg.learning.model
        model = 10 * n_bodies if m.features == "regressor" else nv * m.basis
    per_sample = 20 * params + 6 * nv * learned + 4 * nv * nv + 30 * nv + 3 * nv * model
    if cfg.closed_loop_fit:
        # the closed-loop fit's sensitivities through the loop (feltool.learning.loop_map:
        # per step 2 nv x learned state responses, their forcing and the error rows, and
        # einsum temporaries; the compiled graph's per-step sums D^T D and, for the goals'
        # step on what the weights leave, J^T D), measured: 2550 and 32700 floats per step at
        # 11 and 61 learned parameters on two joints (tests/test_physical.py)
        per_sample += 100 * nv * learned + 5 * learned * learned
    compiled = 0
    if cfg.backend in ("auto", "compiled"):
        # the compiled engine's cycle data (each learned row twice, in three copies while
        # passed), its functions' work and output arrays, and CasADi itself
        per_sample += 24 * learned + 100 * nv
        compiled = 32 * 2**20
    per_cycle = 1024 + 64 * nv  # one metrics row (a dict of floats) kept per cycle
    return _FLOAT * n * per_sample + cfg.sim.cycles * per_cycle + compiled


def available_bytes() -> int | None:
    """Memory this process may still use in [bytes]: MemAvailable, or a cgroup's limit when
    lower; None when neither can be read."""
    found = []
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                found.append(int(line.split()[1]) * 1024)
    except (OSError, ValueError, IndexError):
        pass
    for limit, usage in (("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory.current"),
                         ("/sys/fs/cgroup/memory/memory.limit_in_bytes",
                          "/sys/fs/cgroup/memory/memory.usage_in_bytes")):
        try:
            text = Path(limit).read_text().strip()
            if text != "max" and int(text) < 1 << 60:
                found.append(int(text) - int(Path(usage).read_text().strip()))
        except (OSError, ValueError):
            continue
    if not found:
        try:
            found.append(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
        except (OSError, ValueError, AttributeError):
            return None
    return max(0, min(found))


def _gib(b: float) -> str:
    return f"{b / 2**30:.2f} GiB"


def check_memory(cfg: ExperimentConfig, joints: list[str], n_bodies: int,
                 source: str | None = None, processes: int = 1) -> int:
    """The estimate of :func:`estimate_bytes` for ``processes`` seeds at once; raises
    :class:`ConfigError` (naming period_s and sim.rate_hz, the sizes that drive it) when it
    exceeds :data:`~feltool.bounds.MEMORY_FRACTION` of the memory available. Returns the bytes
    one process needs."""
    need = estimate_bytes(cfg, joints, n_bodies)
    have = available_bytes()
    if have is not None and need * processes > MEMORY_FRACTION * have:
        many = f" x {processes} processes" if processes > 1 else ""
        raise ConfigError([("period_s", f"this run needs about {_gib(need)} per process{many} "
                            f"({cfg.steps_per_cycle} samples per cycle (period_s * sim.rate_hz) "
                            f"x {len(joints)} joints x their RMP parameters), more than "
                            f"{MEMORY_FRACTION:.0%} of the {_gib(have)} available; use a "
                            "shorter period, a lower rate or fewer basis functions"
                            + (" (or fewer --workers)" if processes > 1 else ""))], source)
    return need
