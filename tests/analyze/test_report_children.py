"""The report's figures drawn by child processes: the same page, byte for byte, as drawn here
(an SVG is the same bytes wherever matplotlib draws it)."""

from report_fixtures import synthetic_budget, synthetic_report_data

from normbox_lab.analyze.report import build_html


def test_a_report_drawn_with_a_child_is_the_same_bytes_as_drawn_here():
    # numpy's legacy print options (set by colour-science on import) shape the SVG's clip
    # ids; the child has not imported it: it must draw under this process's options
    import numpy as np

    before = np.get_printoptions()
    np.set_printoptions(legacy="1.13")
    try:
        _check_same_bytes()
    finally:
        np.set_printoptions(**before)


def _check_same_bytes():
    data = synthetic_report_data(step_nm=20.0, seed=3)
    data.polar_materials = ["patch08", "wall"]
    data.budget = synthetic_budget(data)
    here, figs_here, tabs_here = build_html(data, children=0)
    shared, figs_shared, tabs_shared = build_html(data, children=1)
    assert len(figs_here) >= 10
    assert (figs_shared, tabs_shared) == (figs_here, tabs_here)
    assert shared == here
