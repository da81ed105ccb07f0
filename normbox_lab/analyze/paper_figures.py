"""The Normbox paper's published figures, in one table: every number or finding of the paper
that the report, the error budget and the docs quote reads from here.

The paper: Clausen, Marroquim, Fuhrmann, *Acquisition and Validation of Spectral Ground Truth
Data for Predictive Rendering of Rough Surfaces* (Computer Graphics Forum, EGSR 2018).

Each entry carries where the paper says it (section, figure or table), its unit, its sign
convention, the numbers, and `quote`: the one text that a table cell or a sentence prints for
it.  `tests/analyze/test_report_paper_figures.py` reads every quotation of the docs, the report and the
budget against this table.

Sign conventions of the paper (Sec. 4.5.1, Figs. 13/14): NSE = (reference − predicted) /
reference; normbox-lab computes and stores (predicted − reference) / reference
(`ComparisonResult.nse`), so everything shown "as the paper" is the negative of the stored NSE
(`nse_paper_sign`).  The paper does not state the sign of its BRDF fitting error; normbox-lab
shows it as (fit − measured) / measured.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: the paper, as the repository cites it
PAPER = ("Clausen, Marroquim, Fuhrmann: Acquisition and Validation of Spectral Ground Truth "
         "Data for Predictive Rendering of Rough Surfaces")

#: the paper's NSE sign, in words (Sec. 4.5.1)
NSE_PAPER_SIGN = "(reference − prediction)/reference"


@dataclass(frozen=True)
class PaperFigure:
    """One published figure or finding of the paper."""

    key: str
    where: str                      # "Sec. 6.1, Fig. 5(b)/(c)"
    unit: str                       # "%", "ΔE00", "°", "nm", "Pearson r", "" (none)
    sign: str                       # sign convention, or "magnitude" / "none"
    values: tuple[float, ...]       # the numbers the paper gives (empty: a trend)
    quote: str                      # the text every table cell / sentence prints
    says: str                       # what the paper says, in our words (for the reader)

    def cite(self) -> str:
        """"quote (where)", the form the report prints."""
        return f"{self.quote} ({self.where})"


_ENTRIES = (
    # --- what the comparison found (Sec. 6) -------------------------------------------------
    PaperFigure("nrmse_small_band", "Sec. 6.1, Fig. 6(b)", "%", "magnitude", (2.0, 5.0),
                "nearly all within [2, 5] %",
                "at sample angles 30–60° nearly all NRMSE lie in [0.02, 0.05], except patch 24 "
                "and two points of patch 18"),
    PaperFigure("nrmse_by_angle", "Sec. 6.1, Sec. 6.3.4, Fig. 6(a)", "%", "magnitude", (65.0,),
                "flat, then rising from 65°",
                "the NRMSE of all patches (but 24) is nearly on one level at small sample "
                "angles and rises at large ones; the indirect light grows from 65°"),
    PaperFigure("r_radiance_nrmse_large", "Sec. 6.1, Fig. 6(c)", "Pearson r", "negative", (),
                "negative (NRMSE grows as radiance falls)",
                "at 65–90° the NRMSE increases exponentially with decreasing radiance"),
    PaperFigure("r_radiance_rmse", "Sec. 6.1, Fig. 5(b)/(c)", "Pearson r", "positive",
                (0.84, 0.62), "0.84 / 0.62",
                "correlation of radiance and RMSE: 0.84 at 30–60°, 0.62 at 65–90°"),
    PaperFigure("delta_e00", "Sec. 6.1, Fig. 7", "ΔE00", "magnitude", (2.0, 10, 13, 19, 24),
                "most patches < 2 (not discernible side by side); patches 10, 13, 19, 24 "
                "slightly > 2 at some angles",
                "for most patches the differences are below the discernible threshold (2) for "
                "a side-by-side comparison; only patches 10, 13, 19 and 24 are slightly above "
                "it at some angles"),
    PaperFigure("schregle_wienold", "Sec. 6.2, Fig. 8", "%", "magnitude", (2.0, 20),
                "most patches < 2 % (diffuse reflection); patch 20 clearly better than 2 %",
                "Schregle and Wienold's mean deviation is 2 %; most patches of the Normbox are "
                "below 2 %"),
    PaperFigure("baerz_45", "Sec. 6.2, Fig. 9", "ΔE76", "magnitude", (45.0, 1.0),
                "at 45°: mostly below the JND (1)",
                "at 45° the colour differences (ΔE76) are mostly still below the JND"),
    PaperFigure("fit_errors", "Sec. 5.2, Sec. 6.3.2", "%", "magnitude", (5.0, 10.0, 18.0, 18),
                "5–10 %, patch 18 ≈ 18 %",
                "the BRDF fitting errors lie in 5–10 %, patch 18 has 18 %"),
    PaperFigure("fit_weight_w", "Sec. 4.3.2, Figs. 10/11", "", "none",
                (1.0, 4.0, 6.0, 8, 2.0, 18, 4.0),
                "w = 1…4 (twice 6); Fig. 10 (patch 8) w = 2, Fig. 11 (patch 18) w = 4",
                "the cost's weight cos^w θi uses w between 1 and 4, in two cases 6; the paper "
                "publishes w only for patch 8 (Fig. 10, w = 2) and patch 18 (Fig. 11, w = 4)"),
    PaperFigure("polar_wavelength", "Sec. 6.3.2, Figs. 10/11", "nm", "none", (730.0,),
                "730 nm", "the polar plots of patches 8 and 18 are at 730 nm"),
    PaperFigure("fig12_err_d_patch", "Sec. 6.3.3, Fig. 12", "", "none", (22,),
                "err_d from patch 22's fit error",
                "err_d is patch 22's mean fitting error at the direct-light geometry; err_i is "
                "chosen to match the NRMSE within the wall's fitting error"),
    PaperFigure("fig13_patch", "Sec. 6.3.4, Fig. 13", "%", NSE_PAPER_SIGN, (22,),
                "NSE of patch 22, one panel per sample angle",
                "Fig. 13 plots the NSE of patch 22 per sample angle; nearly constant at small "
                "angles, rising from 65°, most at wavelengths above 650 nm"),
    PaperFigure("fig14a", "Sec. 6.3.4, Fig. 14(a)", "%", NSE_PAPER_SIGN, (19, 23, 24, 30.0, 2.0),
                "patches 19, 23, 24 at 30°: follows the fit error, offset ≈ 2 %",
                "the NSE of patches 19, 23, 24 at 30° follows their fitting error (strongly for "
                "19 and 24, moderately for 23), with an offset of about 2 %"),
    PaperFigure("fig14b", "Sec. 6.3.4, Fig. 14(b)", "%", NSE_PAPER_SIGN,
                (21, 90.0, -70.0, 80.0),
                "patch 21 at 90°: rises to the red, as the wall's fit error at (−70°, 80°)",
                "the NSE of patch 21 at 90° rises towards long wavelengths, like the gray "
                "wall's fitting error at θi = −70°, θo = 80°"),
    PaperFigure("nse_65_80", "Sec. 6.3.5, Fig. 13", "%", NSE_PAPER_SIGN, (65.0, 80.0),
                "slightly higher at 65°, slightly lower at 80°, all patches",
                "the NSE at 65° is slightly above and at 80° slightly below the trend of the "
                "neighbouring angles, for all patches: a faulty sample-angle setting"),
    PaperFigure("angle_offsets", "Sec. 6.3.5", "°", "set − true", (65.0, 80.0),
                "(implied: 65° set below, 80° above the true angle)",
                "the paper traces the 65°/80° NSE to the angle setting, without numbers"),
    # --- the rating scale (Sec. 4.5.2) ------------------------------------------------------
    PaperFigure("rating_scale", "Sec. 4.5.2", "ΔE00", "magnitude", (1.0, 2.0, 5.0),
                "1 = JND, 2 = discernible side by side, > 5 easily perceived",
                "ΔE of 1 is the just-noticeable difference, 2 discernible side by side, above "
                "5 easily perceived (Reinhard et al., Color Imaging)"),
    # --- the instruments and error sources (Secs. 4.1, 4.2, 5) -----------------------------
    PaperFigure("cs1000_accuracy", "Sec. 4.1.3, Sec. 5.1", "%", "±", (2.0,), "±2 %",
                "CS-1000A radiometric accuracy ±2 %"),
    PaperFigure("cs1000_wavelength", "Sec. 4.1.3", "nm", "±", (0.3,), "±0.3 nm",
                "CS-1000A spectral accuracy ±0.3 nm"),
    PaperFigure("gonio_calibration", "Sec. 4.2.1, Sec. 5.1", "%", "±", (0.7,), "±0.7 %",
                "the calibrated gonioreflectometer deviates 0.7 % on average"),
    PaperFigure("qepro_snr", "Sec. 5.1", "", "none", (1000.0, 1.0), "1000:1",
                "QE Pro signal-to-noise ratio 1000:1"),
    PaperFigure("qepro_nonlinearity", "Sec. 5.1", "%", "magnitude", (0.5,), "≤ 0.5 %",
                "QE Pro maximal non-linearity 0.5 %"),
    PaperFigure("angle_setting", "Sec. 4.2.3, Sec. 5.1", "°", "±", (1.0,), "±1°",
                "sample angle measured with a phone, ±1°"),
    PaperFigure("geometry", "Sec. 4.2.3, Sec. 5.1", "mm", "±", (1.0,), "±1 mm",
                "geometry measured with a yardstick, ±1 mm"),
    PaperFigure("homogeneity", "Sec. 5.2", "%", "±", (3.0,), "±3 %",
                "light source homogeneity ±3 %"),
    PaperFigure("diffusivity", "Sec. 5.2", "%", "±", (2.6,), "±2.6 %",
                "light source diffusivity ±2.6 %"),
    PaperFigure("lamp_repeatability", "Sec. 5.2, Sec. 6.3.5", "%", "magnitude", (1.0,), "< 1 %",
                "light source repeatability below 1 %"),
    PaperFigure("lamp_delta_e00", "Sec. 5.2", "ΔE00", "magnitude", (0.28,), "max 0.28",
                "the light source's intensity changes gave a maximal ΔE00 of 0.28"),
    PaperFigure("rendering_error", "Sec. 5.3", "", "none", (), "(assumed negligible)",
                "the rendering error is unknown and assumed negligible for Mitsuba"),
)

#: key → entry
PAPER_FIGURES: dict[str, PaperFigure] = {e.key: e for e in _ENTRIES}


def quote(key: str) -> str:
    """The text printed for the paper's figure `key` (KeyError for an unknown key)."""
    return PAPER_FIGURES[key].quote


def cite(key: str) -> str:
    """"quote (where)"."""
    return PAPER_FIGURES[key].cite()


def where(key: str) -> str:
    return PAPER_FIGURES[key].where


def value(key: str, index: int = 0) -> float:
    """A number the paper gives for `key`."""
    return float(PAPER_FIGURES[key].values[index])


def patch_number(key: str, index: int = 0) -> int:
    """A patch number (1…24) the paper names for `key` (Figs. 12–14)."""
    return int(PAPER_FIGURES[key].values[index])


def signed(v: float, decimals: int, *, plus: bool = True) -> str:
    """A number with a fixed count of decimals and a typographic sign: "+0.35", "−0.35"
    (U+2212, never the ASCII hyphen); `plus=False` leaves positive numbers unsigned."""
    text = f"{abs(float(v)):.{decimals}f}"
    if float(text) == 0.0:
        return text
    if v < 0:
        return "\u2212" + text
    return ("+" if plus else "") + text


def nse_paper_sign(nse: np.ndarray) -> np.ndarray:
    """The stored NSE, (prediction − reference)/reference, in the paper's sign."""
    return -np.asarray(nse, dtype=float)


#: the error sources' paper magnitudes (`core.error_sources`, docs/error-budget.md §1):
#: source name → entry key
SOURCES: dict[str, str] = {
    "angle-sweep": "angle_setting",
    "angle-offset": "nse_65_80",
    "geometry": "geometry",
    "cs1000": "cs1000_accuracy",
    "cs1000-wl": "cs1000_wavelength",
    "qepro-snr": "qepro_snr",
    "qepro-nonlin": "qepro_nonlinearity",
    "gonio-cal": "gonio_calibration",
    "homogeneity": "homogeneity",
    "diffusivity": "diffusivity",
    "lamp": "lamp_repeatability",
    "render": "rendering_error",
}

#: the paper-scenario table's observations (`budget_store.paper_observations`, docs/
#: error-budget.md): row label → entry key
OBSERVATIONS: dict[str, str] = {
    "NRMSE at 30–60° within [2, 5] %": "nrmse_small_band",
    "NRMSE by angle, mean over patches (%)": "nrmse_by_angle",
    "r(radiance, NRMSE) 65–90°": "r_radiance_nrmse_large",
    "r(radiance, RMSE) 30–60° / 65–90°": "r_radiance_rmse",
    "BRDF fit errors": "fit_errors",
    "ΔE00": "delta_e00",
    "NSE (paper's sign) at 90° vs wall fit error at (−70°, 80°), r over λ": "fig14b",
    "NSE (paper's sign) at 65° minus its neighbours' mean": "nse_65_80",
    "NSE (paper's sign) at 80° minus its neighbours' mean": "nse_65_80",
    "estimated angle offsets (budget)": "angle_offsets",
}
