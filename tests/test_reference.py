"""The RK4 reference reproduces the measured facts of the paper scenario (shared notes)."""

import numpy as np
import pytest

from sim import scenarios
from sim.reference import rk4_reference


def test_reference_reproduces_the_notes() -> None:
    """Paper gains, fine RK4: the error peaks near 9 m, stays under 10 % of range only after
    about 99 s, is about 4e-4 m at 300 s, and cond(M) settles near 19.5."""
    sc = scenarios.paper()
    t = np.arange(0.0, 300.0 + 1e-9, 0.5)
    ref = rk4_reference(sc, k=0.5, k_star=5.0, t_out_s=t, dt_s=0.01)
    err = np.linalg.norm(ref.xhat_m - sc.x(t), axis=1)
    assert 8.0 < err.max() < 10.0
    above = t[err > 0.1 * np.sqrt(10.0)]
    assert 95.0 < above.max() < 103.0
    assert 2e-4 < err[-1] < 8e-4
    assert ref.cond_m[-1] == pytest.approx(19.5, abs=0.3)


def test_reference_refuses_off_grid_output_times() -> None:
    with pytest.raises(ValueError, match="multiples of dt_s"):
        rk4_reference(
            scenarios.paper(), k=0.5, k_star=5.0, t_out_s=np.array([0.0, 0.013]), dt_s=0.01
        )
