"""The vehicle-side stream checks, on made-up setpoint records: gaps, jumps and
the host's stolen time, charged once to the gap it fell in."""

from __future__ import annotations

import numpy as np

from sitl.host_steal import HostSteal, read_steal
from sitl.stream_checks import check_stream


def record(sent: np.ndarray, speed: float = 1.0) -> dict[str, np.ndarray]:
    """Setpoints along x at ``speed``, sent at ``sent`` and arriving 2 ms later."""
    n = len(sent)
    p = np.zeros((n, 3))
    p[:, 0] = speed * (sent - sent[0])
    return {"wall_time": sent + 0.002, "sent_s": np.round(sent, 3), "position": p,
            "velocity": np.tile([speed, 0, 0], (n, 1)), "acceleration": np.zeros((n, 3)),
            "mode": np.array(["OFFBOARD"] * n)}


def stream_with_gap(gap_s: float, at: int = 100, n: int = 300) -> np.ndarray:
    t = np.arange(n) * 0.02
    t[at:] += gap_s - 0.02
    return t + 1000.0


def steal_at(t0: float, amount: float, cpu: int = 0) -> HostSteal:
    """Counters sampled every 10 ms, ``amount`` accounted to ``cpu`` at ``t0``."""
    t = np.arange(900.0, 1020.0, 0.01)
    steal = np.zeros((len(t), 2))
    steal[t >= t0, cpu] = amount
    return HostSteal(t, steal)


def test_a_gap_over_budget_is_a_problem_and_a_steady_stream_is_not():
    assert not check_stream(record(stream_with_gap(0.02)), 2.0).problems()
    figures = check_stream(record(stream_with_gap(0.12)), 2.0)
    assert abs(figures.max_gap_s - 0.12) < 1e-9
    assert figures.problems() == ["gap of 120 ms > 100 ms"]


def test_a_gap_is_measured_net_of_the_time_the_host_took_within_it():
    sent = stream_with_gap(0.125)
    end = sent[100]  # the stream resumed here: the host's time is accounted then
    figures = check_stream(record(sent), 2.0, host_steal=steal_at(end + 0.004, 0.1))
    assert abs(figures.max_gap_s - 0.025) < 1e-9, figures.summary()
    assert figures.host_steal_gaps == 1 and abs(figures.host_steal_s - 0.1) < 1e-9
    assert abs(figures.max_gap_with_steal_s - 0.125) < 1e-9
    assert "took a CPU away" in figures.summary()
    assert not figures.problems()


def test_steal_elsewhere_excuses_nothing_and_one_gap_is_charged_once():
    sent = stream_with_gap(0.125)
    far = check_stream(record(sent), 2.0, host_steal=steal_at(sent[200], 0.1))
    assert abs(far.max_gap_s - 0.125) < 1e-9 and far.problems()
    # both CPUs taken at once: the stream was on one of them, one charge
    both = steal_at(sent[100] + 0.004, 0.1)
    both = HostSteal(both.t, both.steal + steal_at(sent[100] + 0.004, 0.08, cpu=1).steal)
    figures = check_stream(record(sent), 2.0, host_steal=both)
    assert abs(figures.max_gap_s - 0.025) < 1e-9 and abs(figures.host_steal_s - 0.1) < 1e-9
    # a larger gap than the host took stays a problem
    sent = stream_with_gap(0.25)
    figures = check_stream(record(sent), 2.0, host_steal=steal_at(sent[100] + 0.004, 0.1))
    assert abs(figures.max_gap_s - 0.15) < 1e-9 and figures.problems()


def test_the_counters_read_on_this_machine():
    steal = read_steal()
    assert steal.ndim == 1 and np.all(steal >= 0)


def test_a_gap_a_tick_shorter_than_the_hosts_time_is_charged_its_excess_only():
    sent = stream_with_gap(0.105)  # woken on the other CPU 15 ms before the first ran again
    figures = check_stream(record(sent), 2.0, host_steal=steal_at(sent[100] + 0.004, 0.12))
    assert abs(figures.host_steal_s - 0.085) < 1e-9 and abs(figures.max_gap_s - 0.02) < 1e-9
    sent = stream_with_gap(0.09)  # too short to hold it: the host took another CPU
    figures = check_stream(record(sent), 2.0, host_steal=steal_at(sent[100] + 0.004, 0.12))
    assert figures.host_steal_s == 0.0 and abs(figures.max_gap_s - 0.09) < 1e-9


def test_a_step_after_a_gap_is_excused_up_to_the_stall_budget_only():
    # 2 m/s along x, allowed 2.2 m/s: after a 0.2 s gap the plan goes on where the
    # clock says (0.4 m further), within the 0.25 s budget
    assert not check_stream(record(stream_with_gap(0.2), speed=2.0), 2.2).jumps
    # after a 0.5 s gap it must not (a stalled stream resumed where the clock says)
    late = check_stream(record(stream_with_gap(0.5), speed=2.0), 2.2)
    assert late.jumps == 1 and abs(late.largest_jump_m - 1.0) < 1e-9
    # a tighter budget excuses less
    assert check_stream(record(stream_with_gap(0.2), speed=2.0), 2.2, max_step_dt=0.1).jumps


def test_a_tick_of_steal_excuses_nothing():
    sent = stream_with_gap(0.03)
    figures = check_stream(record(sent), 2.0, host_steal=steal_at(sent[100] + 0.004, 0.01))
    assert figures.host_steal_s == 0.0 and abs(figures.max_gap_s - 0.03) < 1e-9


def test_a_gap_is_charged_on_the_senders_clock_when_the_receiver_was_held_up_too():
    """The host took the CPU of both the stream and the vehicle's receiver: the
    setpoint before the gap was taken in 110 ms late, after the host's time was
    over; the send gap (137 ms: 100 taken, 36 waiting for a CPU) still holds it."""
    sent = stream_with_gap(0.137)
    rec = record(sent)
    rec["wall_time"][99] = sent[99] + 0.112
    figures = check_stream(rec, 2.0, host_steal=steal_at(sent[99] + 0.105, 0.1))
    assert figures.host_steal_gaps == 1 and abs(figures.host_steal_s - 0.1) < 1e-9
    assert abs(figures.max_gap_s - 0.037) < 1e-9 and not figures.problems(), figures.summary()


def test_a_gap_spanning_a_pause_by_send_stamps_is_the_pauses_even_if_it_arrived_after():
    """The service frozen for 0.5 s: the setpoint sent just before the freeze sat in
    its MAVSDK's socket and arrived after it. The 0.5 s between its stamp and the next
    is the pause (left out); a gap elsewhere still counts."""
    sent = stream_with_gap(0.5, at=101)
    rec = record(sent)
    rec["wall_time"][100] = sent[101] - 0.001  # (arrived with the resume)
    pause = (sent[100] + 0.005, sent[101] - 0.002)
    assert not check_stream(rec, 2.0, pauses=[pause]).problems()
    late = stream_with_gap(0.5, at=101)
    late[200:] += 0.2  # a real gap later on
    assert check_stream(record(late), 2.0, pauses=[pause]).problems() == \
        ["gap of 220 ms > 100 ms"]
