"""LogTimeOrder against hand-worked cases: nearly ordered arrivals come out sorted, nothing is
held longer than the window or beyond the cap, a late message goes out at once and is counted."""

from common.record.order import LogTimeOrder


def test_nearly_ordered_arrivals_come_out_sorted():
    order = LogTimeOrder(hold_ns=10)
    out = []
    for t in (0, 5, 3, 12, 11, 20, 15, 31, 40):
        out += order.push(t, t)
    out += order.drain()
    assert out == [0, 3, 5, 11, 12, 15, 20, 31, 40] and order.late == 0


def test_the_window_and_the_cap_bound_what_is_held():
    order = LogTimeOrder(hold_ns=10)
    assert order.push(0, "a") == [] and order.push(9, "b") == []
    assert order.push(10, "c") == ["a"]  # 0 is now 10 behind the newest
    capped = LogTimeOrder(hold_ns=10**9, max_held=2)
    assert capped.push(1, 1) == [] and capped.push(2, 2) == [] and capped.push(3, 3) == [1] and len(capped) == 2


def test_a_late_message_is_released_at_once_and_counted():
    order = LogTimeOrder(hold_ns=5)
    released = order.push(0, 0) + order.push(10, 10)
    assert released == [0]
    assert order.push(-3, "late") == ["late"] and order.late == 1  # older than one released: not held
    assert order.drain() == [10]
