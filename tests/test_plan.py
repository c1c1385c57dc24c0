"""Measurement batches sized from the run's cores and the session's length (plan.batch_frames)."""

import pytest

from huefringe.plan import batch_frames


@pytest.mark.parametrize("n", [0, 1, 2, 3, 4, 5, 19, 20, 21, 199, 200, 251, 600, 1000, 1001])
@pytest.mark.parametrize("cores", [1, 2, 3, 4, 8])
@pytest.mark.parametrize("cap", [1, 7, 100, 250])
def test_batches_cover_the_session_in_order_within_the_cap(n, cores, cap):
    frames = list(range(10, 10 + n))
    batches = batch_frames(frames, cores, cap)
    assert [f for b in batches for f in b] == frames  # every frame once, in order
    assert all(1 <= len(b) <= cap for b in batches)
    if batches:
        sizes = [len(b) for b in batches]
        assert max(sizes) - min(sizes) <= 1  # balanced
        assert len(batches) == min(n, len(batches))
        # as few jobs as the cap allows, rounded up to a multiple of the cores (no idle core in
        # the last round), but never more jobs than frames
        need = -(-n // cap)
        assert len(batches) == min(n, -(-need // cores) * cores)


@pytest.mark.parametrize("cores", [1, 2, 4, 8])
@pytest.mark.parametrize("per_core", [2, 3, 10, 125])
def test_two_frames_per_core_keep_every_core_busy(cores, per_core):
    batches = batch_frames(list(range(cores * per_core)), cores, cap=250)
    assert len(batches) >= cores
    assert len(batches) % cores == 0


def test_issue_cases():
    # 200 frames on 2 cores used to be one job of 200 (one core idle); 1000 stays 4 jobs of 250
    assert [len(b) for b in batch_frames(list(range(200)), 2, 250)] == [100, 100]
    assert [len(b) for b in batch_frames(list(range(1000)), 2, 250)] == [250] * 4
    assert [len(b) for b in batch_frames(list(range(20)), 2, 250)] == [10, 10]
    assert [len(b) for b in batch_frames(list(range(600)), 2, 250)] == [150] * 4
    assert batch_frames([5], 4, 250) == [[5]]
    assert batch_frames([], 2, 250) == []
    assert [len(b) for b in batch_frames(list(range(10)), 0, 250)] == [10]  # no cores given: one


def test_bad_cap_is_refused():
    with pytest.raises(ValueError, match="at least 1"):
        batch_frames([0, 1], 2, 0)
