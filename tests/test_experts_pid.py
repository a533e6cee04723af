"""PID: proportional, integral, derivative on measurement, limits, anti-windup, on
hand-computed cases."""
import math

import pytest

from sebvs.experts.pid import PID, PIDGains


def test_p_only_and_output_limits():
    pid = PID(PIDGains(kp=2.0, out_min=-1.0, out_max=1.0))
    assert pid.update(0.3, 0.0, 0.1) == pytest.approx(0.6)
    assert pid.update(1.0, 0.0, 0.1) == 1.0 and pid.saturated and pid.raw == pytest.approx(2.0)
    assert pid.update(-5.0, 0.0, 0.1) == -1.0


def test_integral_accumulates_with_dt():
    pid = PID(PIDGains(kp=0.0, ki=1.0, out_min=-10, out_max=10))
    # clamp mode integrates before the output: 0.5*0.1, then + 0.5*0.3
    assert pid.update(0.5, 0.0, 0.1) == pytest.approx(0.05)
    assert pid.update(0.5, 0.0, 0.3) == pytest.approx(0.20)
    assert pid.update(0.5, 0.0, 0.0) == pytest.approx(0.20)     # dt 0: unchanged


def test_derivative_on_measurement_has_no_setpoint_kick():
    pid = PID(PIDGains(kp=0.0, kd=1.0, out_min=-10, out_max=10))
    assert pid.update(0.0, 0.0, 0.1) == 0.0            # first call: no derivative
    assert pid.update(5.0, 0.0, 0.1) == 0.0            # setpoint step, measurement still
    assert pid.update(5.0, 0.2, 0.1) == pytest.approx(-2.0)   # -kd * 0.2 / 0.1


def test_derivative_filter_is_first_order():
    pid = PID(PIDGains(kp=0.0, kd=1.0, tau_d=0.1, out_min=-10, out_max=10))
    pid.update(0.0, 0.0, 0.1)
    a = 1 - math.exp(-1.0)
    assert pid.update(0.0, 0.1, 0.1) == pytest.approx(-1.0 * a)


def test_clamping_stops_windup_and_recovers_at_once():
    g = dict(kp=1.0, ki=1.0, out_min=-1.0, out_max=1.0)
    clamp, free = PID(PIDGains(**g, anti_windup="clamp")), PID(PIDGains(**g, anti_windup="none"))
    for _ in range(100):                                # 10 s of a large error
        clamp.update(2.0, 0.0, 0.1)
        free.update(2.0, 0.0, 0.1)
    assert clamp.integral == pytest.approx(0.0) and free.integral == pytest.approx(20.0)
    # error reverses: the clamped controller follows at once, the wound-up one stays high
    assert clamp.update(-0.5, 0.0, 0.1) == pytest.approx(-0.5 - 0.05)
    assert free.update(-0.5, 0.0, 0.1) == 1.0


def test_clamping_integrates_once_the_error_pulls_out_of_saturation():
    pid = PID(PIDGains(kp=1.0, ki=1.0, out_min=-1.0, out_max=1.0))
    pid.update(0.5, 0.0, 1.0)                           # I = 0.5, u = 1.0 (not beyond)
    assert pid.integral == pytest.approx(0.5)
    pid.update(0.8, 0.0, 1.0)                           # would be 0.8 + 1.3: frozen
    assert pid.integral == pytest.approx(0.5) and pid.output == 1.0
    pid.update(-0.2, 0.0, 1.0)                          # pulls down: integrates
    assert pid.integral == pytest.approx(0.3)
    assert pid.output == pytest.approx(0.1)


def test_back_calculation_bleeds_the_excess():
    pid = PID(PIDGains(kp=1.0, ki=1.0, kb=2.0, out_min=-1.0, out_max=1.0,
                       anti_windup="backcalc"))
    # step 1: u_raw = 2 + 0 -> 1; I += 1 * (1*2 + 2*(1 - 2)) = 0
    assert pid.update(2.0, 0.0, 1.0) == 1.0
    assert pid.integral == pytest.approx(0.0)
    # a smaller dt: u_raw = 2 + 0 = 2 -> 1; I += 0.1 * (2 + 2 * (1 - 2)) = 0
    pid.update(2.0, 0.0, 0.1)
    assert pid.integral == pytest.approx(0.0)
    # unsaturated: plain integration, I += 0.1 * 0.5
    pid.update(0.5, 0.0, 0.1)
    assert pid.integral == pytest.approx(0.05)
    # the integral stays bounded under a sustained large error
    for _ in range(200):
        pid.update(5.0, 0.0, 0.05)
    assert pid.integral < 3.0 and pid.output == 1.0


def test_integral_limits_and_reset():
    pid = PID(PIDGains(kp=0.0, ki=1.0, i_min=-0.2, i_max=0.2, out_min=-5, out_max=5))
    for _ in range(10):
        pid.update(1.0, 0.0, 0.1)
    assert pid.integral == pytest.approx(0.2) and pid.output == pytest.approx(0.2)
    pid.reset()
    assert pid.integral == 0.0 and pid.prev_meas is None and pid.output == 0.0


def test_bad_gains_are_refused():
    with pytest.raises(ValueError, match="out_min"):
        PIDGains(out_min=1.0, out_max=-1.0)
    with pytest.raises(ValueError, match="anti_windup"):
        PIDGains(anti_windup="magic")
