"""``./rwpend bench``'s output directory: the bags an earlier bench kept (``--keep-bags``) are
never overwritten by the next one; it refuses before any run."""
from rwpend_bench import bench


def test_bags_kept_by_an_earlier_bench_are_refused(tmp_path, capsys):
    kept = tmp_path / 'rt_loop_h1000us'
    kept.mkdir()
    (kept / 'metadata.yaml').write_text('mine')
    assert bench.main(['--out', str(tmp_path), '--quick']) == 2
    err = capsys.readouterr().err
    assert 'earlier bench' in err and str(kept) in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ['rt_loop_h1000us']
    assert (kept / 'metadata.yaml').read_text() == 'mine'


def test_an_out_that_is_a_file_is_refused(tmp_path, capsys):
    f = tmp_path / 'x'
    f.write_text('mine')
    assert bench.main(['--out', str(f)]) == 2
    assert 'not a directory' in capsys.readouterr().err and f.read_text() == 'mine'
