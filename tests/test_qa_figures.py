"""The calibration QA figures: error axes with a unit, legends off the data."""

from __future__ import annotations

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from huefringe import colour, compensation, phase_error  # noqa: E402

TWO_PI = 2 * np.pi


def _legends_off_their_axes(fig) -> int:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(fig)  # the figure may have been closed (pyplot) after writing
    canvas.draw()
    renderer = canvas.get_renderer()
    n = 0
    for ax in fig.axes:
        leg = ax.get_legend()
        if leg is None:
            continue
        box, frame = leg.get_window_extent(renderer), ax.get_window_extent(renderer)
        assert not box.overlaps(frame), (ax.get_title(loc="left"), box, frame)
        for other in fig.axes:  # nor on a neighbouring panel's data
            assert not box.overlaps(other.get_window_extent(renderer)), (ax.get_title(loc="left"), other)
        n += 1
    return n


def test_hue_cross_section_figure_error_in_mrad_and_legends_off_the_data(tmp_path, monkeypatch):
    seen = []
    write = compensation.write_figure_png
    monkeypatch.setattr(compensation, "write_figure_png", lambda fig, out, dpi: (seen.append(fig), write(fig, out, dpi))[1])
    x = np.arange(400)
    true = TWO_PI * x / 60
    rng = np.random.default_rng(3)
    raw = np.mod(true + 0.03 * np.sin(6 * true) + rng.normal(0, 0.01, x.size), TWO_PI)
    cor = np.mod(true + rng.normal(0, 0.01, x.size), TWO_PI)
    out = compensation.hue_cross_section_figure(raw, cor, true, tmp_path / "cross.png")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    fig = seen[0]
    main, strip = fig.axes[0::2], fig.axes[1::2]
    assert [a.get_ylabel() for a in main] == ["phase (rad)"] * 2
    assert [a.get_ylabel() for a in strip] == ["error\n(mrad)"] * 2
    for ax, y in zip(strip, (raw, cor), strict=True):
        err_mrad = 1e3 * colour.wrap_pi(y - np.mod(true, TWO_PI))
        np.testing.assert_allclose(ax.lines[0].get_ydata(), err_mrad, atol=1e-6)
        rms = np.sqrt(np.mean(err_mrad**2))
        assert ax.get_title(loc="left") == f"error against the true code phase: RMS {rms:.1f} mrad"
    assert 30 > np.sqrt(np.mean(strip[0].lines[0].get_ydata() ** 2)) > 15  # 0.03 rad ripple + noise, in mrad
    assert _legends_off_their_axes(fig) == 2


def test_phase_error_qa_figure_legend_off_the_data(tmp_path, monkeypatch):
    closed = []
    close = plt.close
    monkeypatch.setattr(plt, "close", lambda fig=None: (closed.append(fig), None)[1])
    n = 256
    c = (np.arange(n) + 0.5) * TWO_PI / n
    e = 0.01 * np.sin(6 * c)
    lut = phase_error.PhaseErrorLUT(error=e, before=e + 0.001, after=np.full(n, 0.001),
                                    stats={"binned_rms_before_rad": 0.0072, "binned_rms_after_rad": 0.0033})
    phase_error.qa_figure(lut, str(tmp_path / "pe.png"))
    assert (tmp_path / "pe.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    (fig,) = closed
    (ax,) = fig.axes
    assert "(mrad)" in ax.get_ylabel()
    assert [t.get_text() for t in ax.get_legend().get_texts()][:2] == ["before (rms 7.2 mrad)", "after (rms 3.3 mrad)"]
    assert _legends_off_their_axes(fig) == 1
    close(fig)
