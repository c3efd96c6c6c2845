"""``./rwpend soak``'s output: a run judges only the bags it recorded (an earlier soak's bags,
judged, would pass for its own when ``up`` fails at once), and never overwrites them."""
import pytest

from rwpend_bench import soak


def test_an_earlier_soaks_bag_is_refused_before_anything_runs(tmp_path, capsys):
    (tmp_path / 'soak_loop').mkdir()
    with pytest.raises(SystemExit) as exc:
        soak.main(['--out', str(tmp_path), '--layouts', 'loop,control'])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert 'earlier soak' in err and str(tmp_path / 'soak_loop') in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ['soak_loop'], 'nothing else written'


def test_run_layout_refuses_an_existing_bag(tmp_path):
    (tmp_path / 'soak_control').mkdir()
    with pytest.raises(ValueError, match='already exists'):
        soak.run_layout('control', 30.0, [], tmp_path, load=False)
    assert [p.name for p in tmp_path.iterdir()] == ['soak_control']


def test_the_default_output_is_new_for_every_soak(tmp_path, monkeypatch):
    """Two ``make soak`` one after the other each write a directory of their own."""
    monkeypatch.setattr(soak, 'ROOT', tmp_path)
    seen = []
    monkeypatch.setattr(soak, 'run_layout', lambda layout, d, f, out, load: seen.append(out) or
                        {'layout': layout, 'ok': True, 'up_status': 0, 'stalls_injected': 0,
                         'verdict': {'gaps': {}, 'recover_s': [], 'resyncs': 0, 'falls': 0,
                                     'recoveries': 0, 'unsafe_samples': 0, 'latched': [], 'problems': []}})
    assert soak.main(['--layouts', 'loop', '--no-load']) == 0
    assert seen[0].parent == tmp_path / 'soak_out' and seen[0].name[:2] == '20'


def test_an_out_that_is_a_file_is_refused(tmp_path, capsys):
    f = tmp_path / 'x'
    f.write_text('mine')
    with pytest.raises(SystemExit) as exc:
        soak.main(['--out', str(f)])
    assert exc.value.code == 2 and 'not a directory' in capsys.readouterr().err
    assert f.read_text() == 'mine'


@pytest.mark.system      # starts ./rwpend up (which stops at its arguments)
def test_an_up_that_records_nothing_is_a_failed_soak_run(tmp_path):
    """``up`` refused at once (here: an option it does not know): the run fails, saying there is
    no bag, instead of stopping the soak with a traceback."""
    r = soak.run_layout('loop', 30.0, [], tmp_path, load=False, extra=['--no-such-option'])
    assert not r['ok'] and r['up_status'] == 2, r
    assert any('no bag' in p for p in r['verdict']['problems']), r['verdict']['problems']
    assert soak.summary([r]).splitlines()[2].split()[:3] == ['loop', 'NO', '2']
