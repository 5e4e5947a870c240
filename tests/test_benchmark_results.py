"""The benchmark scripts' shared writers (``benchmarks/_results.py``)."""

from pathlib import Path

import pytest

BENCHMARKS = Path(__file__).resolve().parent.parent / "benchmarks"


def test_a_benchmark_figure_is_replaced_whole_or_not_at_all(tmp_path, monkeypatch):
    # A run stopped while it draws (Ctrl-C, a kill, a full disk) must leave the last run's
    # figure, not a truncated PNG in its place, nor a temporary file beside it.
    pytest.importorskip("matplotlib")
    from matplotlib.figure import Figure

    monkeypatch.syspath_prepend(str(BENCHMARKS))
    import _results

    png = tmp_path / "study" / "cost_vs_c.png"  # (a folder not made yet)
    series = {"one GN iteration": ([1, 2, 3], [0.1, 0.2, 0.4], None)}
    _results.plot_lines(series, "C", "wall time (s)", png)
    before = png.read_bytes()
    assert before.startswith(b"\x89PNG")

    def torn(self, target, **kwargs):  # half an image, to a file object or a path
        if isinstance(target, (str, Path)):
            Path(target).write_bytes(b"\x89PNG half an ima")
        else:
            target.write(b"\x89PNG half an ima")
        raise KeyboardInterrupt

    monkeypatch.setattr(Figure, "savefig", torn)
    with pytest.raises(KeyboardInterrupt):
        _results.plot_lines(series, "C", "wall time (s)", png)
    assert png.read_bytes() == before
    assert [p.name for p in png.parent.iterdir()] == ["cost_vs_c.png"]
