"""The per-rig feed of decimated rows that page streams read at their own pace."""
from rwpend_console.feed import Feed

S = 1_000_000_000


def test_rows_since_a_cursor():
    f = Feed()
    f.add_status(0, True, 1.0, False, 'auto', 'swingup')
    f.add_state(0, 5 * S, 0.1, 0.2, 3.0, 0.5)
    first, cur = f.since(None, 20.0)
    assert first['reset'] and first['b'] == [[0.0, 'auto', 'swingup']] and len(first['s']) == 1
    assert first['s'][0] == [0.0, 0.1, 0.2, 3.0, 0.5, 5000.0]
    assert first['u'] == [[0.0, 1.0, False]]
    f.add_state(S // 50, 5 * S, 0.11, 0.2, 3.0, 0.5)
    f.add_status(S // 50, False, 2.0, False, 'auto', 'swingup')      # decimated away, same band
    f.add_status(S // 40, False, 9.0, True, 'auto', 'catch')         # band change: always kept
    nxt, cur2 = f.since(cur, 20.0, first['gen'])
    assert not nxt['reset'] and len(nxt['s']) == 1 and nxt['u'] == [] and nxt['b'] == [[0.025, 'auto', 'catch']]
    empty, cur3 = f.since(cur2, 20.0, first['gen'])
    assert (empty['s'], empty['u'], empty['b'], cur3) == ([], [], [], cur2)


def test_a_late_page_gets_the_window_and_the_band_in_force():
    f = Feed()
    f.add_status(0, True, 0.0, False, 'auto', 'swingup')
    for k in range(0, 60 * 50):                        # 60 s at 50 Hz, caught at 30 s
        f.add_state(k * S // 50, 0, 0.0, 0.0, 0.0, 0.0)
        if k == 30 * 50:
            f.add_status(30 * S, True, 0.0, False, 'auto', 'balance')
    batch, _ = f.since(None, 20.0)
    assert batch['s'][0][0] >= 39.98 - 1e-9 and len(batch['s']) == 1001
    assert batch['b'] == [[30.0, 'auto', 'balance']]


def test_a_new_run_starts_a_new_generation():
    f = Feed()
    f.add_state(100 * S, 0, 0.0, 0.0, 0.0, 0.0)
    _, cur = f.since(None, 20.0)
    f.add_state(0, 0, 1.0, 0.0, 0.0, 0.0)             # the simulator restarted
    batch, _ = f.since(cur, 20.0, 0)
    assert batch['reset'] and batch['gen'] == 1 and [r[1] for r in batch['s']] == [1.0]


def test_memory_is_bounded():
    f = Feed(keep_rows=100)
    for k in range(1000):
        f.add_state(k * 1000, 0, 0.0, 0.0, 0.0, 0.0)
    batch, _ = f.since(None, 1e9)
    assert len(batch['s']) == 100


def test_the_applied_command_beside_what_the_controller_sent():
    """``a`` rows: what the motor got (zero under the e-stop while the controller sends 10); the
    motor lag's subnormal leftovers come as exactly 0."""
    f = Feed()
    f.add_status(0, True, 10.0, True, 'auto', 'swingup')
    f.add_applied(0, 5e-324)
    f.add_applied(S // 50, -5e-324)
    f.add_applied(2 * S // 50, 7.5)
    f.add_status(S // 50, True, -3e-12, False, 'auto', 'swingup')
    batch, cur = f.since(None, 20.0)
    assert batch['a'] == [[0.0, 0.0], [0.02, 0.0], [0.04, 7.5]]
    assert batch['u'] == [[0.0, 10.0, True], [0.02, 0.0, False]]
    f.add_applied(3 * S // 50, 1.0)
    nxt, _ = f.since(cur, 20.0, batch['gen'])
    assert nxt['a'] == [[0.06, 1.0]] and nxt['s'] == [] and nxt['u'] == []
