"""Where the public logs of the log readers' tests are, and one emitted gimbal flight as a
tlog with its DataFlash and ULog twins (``python -m sim convert``)."""

from __future__ import annotations

from pathlib import Path

from sim import emitter as em
from sim import logwriters, scenarios

LOGS = Path(__file__).resolve().parent / "data" / "logs"


def make_flight(d: Path) -> dict[str, Path]:
    cfg = em.EmitterConfig(bearing="gimbal", duration_s=90.0, seed=2, bearing_noise_deg=0.5)
    emitter = em.Emitter(scenarios.make("orbit"), cfg)
    tlog, truth = d / "f.tlog", d / "f.truth.jsonl"
    em.run(emitter, tlog=tlog, truth=truth)
    out = {"tlog": tlog, "truth": truth}
    for fmt in ("bin", "ulg"):
        out[fmt] = d / f"f.{fmt}"
        logwriters.convert(tlog, out[fmt])
        out[f"{fmt}_truth"] = d / f"f.{fmt}.truth.jsonl"
        logwriters.convert_truth(truth, out[f"{fmt}_truth"], out[fmt])
    return out
