"""SampleOrder: duplicates and out-of-order frames dropped, a reboot told apart from stale frames."""

from __future__ import annotations

import pytest

from tepinn_flight.live.sample_order import SampleOrder

P = 0.0025  # 400 Hz


def _run(order, times, arrivals=None):
    arrivals = arrivals or [None] * len(times)
    return [order.accept(t, a) for t, a in zip(times, arrivals)]


def test_in_order_stream_is_all_accepted():
    o = SampleOrder()
    assert set(_run(o, [10 + k * P for k in range(100)])) == {"accept"}
    assert o.counts["accept"] == 100 and o.dropped == 0


def test_duplicates_of_the_latest_and_of_recent_samples():
    o = SampleOrder()
    _run(o, [1.0, 1.01, 1.02])
    assert o.accept(1.02) == "duplicate"  # the latest again
    assert o.accept(1.0) == "duplicate"  # an earlier accepted one
    assert o.accept(1.03) == "accept"
    assert o.counts == {"accept": 4, "duplicate": 2, "stale": 0, "reboot": 0}


def test_isolated_old_frames_among_newer_ones_are_stale_never_a_reboot():
    o = SampleOrder(recent=4)
    times = [50 + k * P for k in range(400)]
    out = []
    for k, t in enumerate(times):
        out.append(o.accept(t, k * P))
        if k % 20 == 10:  # an old copy (beyond the recent window), every 20 samples, counting up too
            out.append(o.accept(t - 2.0, k * P))
    assert out.count("reboot") == 0 and out.count("stale") == 20 and out.count("accept") == 400


def test_a_reordered_pair_drops_the_late_one():
    o = SampleOrder()
    t = [k * P for k in range(10)]
    seq = [*t[:4], t[5], t[4], *t[6:]]
    assert _run(o, seq) == ["accept"] * 5 + ["stale"] + ["accept"] * 4


def test_reboot_needs_consecutive_counting_frames_and_silence():
    o = SampleOrder(confirm_n=5, silence_s=0.25)
    _run(o, [100 + k * P for k in range(40)], [k * P for k in range(40)])
    t_end = 39 * P
    # the autopilot reboots: 1.5 s of silence, then its clock counts up from 2.0 s
    new = [2.0 + k * P for k in range(10)]
    arr = [t_end + 1.5 + k * P for k in range(10)]
    assert _run(o, new, arr) == ["stale"] * 4 + ["reboot"] + ["accept"] * 5
    assert o.last == new[-1] and o.counts["reboot"] == 1


def test_a_burst_of_old_copies_is_not_a_reboot_while_the_live_link_is_fresh():
    o = SampleOrder(confirm_n=5, silence_s=0.25)
    _run(o, [100 + k * P for k in range(400)], [k * P for k in range(400)])
    now = 400 * P
    burst = [99.0 + k * P for k in range(20)]  # a redundant link flushing 20 buffered old frames
    assert set(_run(o, burst, [now + 1e-4 * k for k in range(20)])) == {"stale"}
    assert o.accept(100 + 400 * P, now + 0.003) == "accept"  # the live timeline goes on
    assert o.counts["reboot"] == 0


def test_without_arrival_times_the_count_alone_decides():
    o = SampleOrder(confirm_n=3)
    _run(o, [5.0, 5.1, 5.2])
    assert _run(o, [0.5, 0.6, 0.7, 0.8]) == ["stale", "stale", "reboot", "accept"]


def test_a_newer_frame_cancels_the_candidate_and_inconsistent_steps_restart_it():
    o = SampleOrder(confirm_n=3)
    _run(o, [5.0, 5.1])
    assert _run(o, [1.0, 1.1, 5.2, 1.2, 1.3]) == ["stale", "stale", "accept", "stale", "stale"]
    assert o.accept(1.4) == "reboot"
    o2 = SampleOrder(confirm_n=3, max_step_s=0.5)
    _run(o2, [5.0, 5.1])
    assert _run(o2, [1.0, 1.1, 3.0, 3.1, 3.2]) == ["stale", "stale", "stale", "stale", "reboot"]  # 1.1→3.0 too far
    assert o2.accept(3.2) == "duplicate"


def test_reset_forgets_the_timeline_but_keeps_the_counts():
    o = SampleOrder()
    _run(o, [3.0, 3.1, 3.0])
    o.reset()
    assert o.accept(1.0) == "accept" and o.counts["duplicate"] == 1 and o.counts["accept"] == 3


def test_bad_parameters():
    with pytest.raises(ValueError):
        SampleOrder(confirm_n=1)
