"""bulgekit litho's tone model: sRGB pictures decoded to luminance and L* (checked against
scikit-image's own conversions and the sRGB figures), the tone curves, the predicted look in L*,
the end columns of a planar plate, and the calibration plate."""
from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image
from skimage.color import rgb2lab, rgb2xyz

from bulgekit import litho as lt
from bulgekit.litho import calibration, picture, tone
from bulgekit.cli import main


def lib_Y(rgb):
    """Y of sRGB values 0..1 (..., 3) by scikit-image."""
    rgb = np.asarray(rgb, float)
    return rgb2xyz(rgb.reshape(-1, 1, 3)).reshape(rgb.shape)[..., 1]


def lib_L(rgb):
    rgb = np.asarray(rgb, float)
    return rgb2lab(rgb.reshape(-1, 1, 3)).reshape(rgb.shape)[..., 0]


# --- decoding ------------------------------------------------------------------------------------

def test_known_greys():
    # sRGB 128 is Y 0.2159, L* 53.59; 119 is L* 50.03; white 1, 100; black 0, 0 (IEC 61966-2-1, CIE 1976)
    v = np.array([0, 119, 128, 255]) / 255
    assert tone.grey_to_luminance(v) == pytest.approx([0, 0.18447, 0.21586, 1], abs=2e-5)
    assert tone.lightness(tone.grey_to_luminance(v)) == pytest.approx([0, 50.03, 53.585, 100], abs=0.02)
    grey = np.repeat(v[:, None], 3, axis=1)
    assert tone.lightness(tone.grey_to_luminance(v)) == pytest.approx(lib_L(grey), abs=1e-6)
    # round trips: L* -> Y -> L*, Y -> sRGB -> Y
    L = np.linspace(0, 100, 11)
    assert tone.lightness(tone.luminance(L)) == pytest.approx(L, abs=1e-6)
    Y = np.linspace(0, 1, 11)
    assert tone.grey_to_luminance(tone.to_srgb(Y)) == pytest.approx(Y, abs=1e-4)


def test_decode_8_and_16_bit_grey(tmp_path):
    g8 = np.array([[0, 64, 128, 200, 255]] * 3, np.uint8)
    Image.fromarray(g8).save(tmp_path / "g8.png")
    Y = picture.read_luminance(tmp_path / "g8.png")
    assert Y.shape == (3, 5)
    assert Y[1] == pytest.approx(lib_Y(np.repeat(g8[1, :, None] / 255, 3, axis=1)), abs=1e-6)
    g16 = np.array([[0, 1000, 32768, 50000, 65535]] * 3, np.uint16)
    Image.fromarray(g16).save(tmp_path / "g16.png")
    assert Image.open(tmp_path / "g16.png").mode.startswith("I")          # really 16 bits
    Y16 = picture.read_luminance(tmp_path / "g16.png")
    assert Y16[0] == pytest.approx(lib_Y(np.repeat(g16[0, :, None] / 65535, 3, axis=1)), abs=1e-6)
    # 1000/65535 is between two 8-bit values: the 16 bits are kept
    assert Y16[0, 1] != pytest.approx(lib_Y([4 / 255] * 3), abs=1e-5)


def test_decode_colour_and_alpha(tmp_path):
    rgb = np.array([[[255, 0, 0], [0, 255, 0], [0, 0, 255], [10, 200, 30]]], np.uint8)
    Image.fromarray(rgb).save(tmp_path / "rgb.png")
    Y = picture.read_luminance(tmp_path / "rgb.png")[0]
    assert Y[:3] == pytest.approx([0.2126, 0.7152, 0.0722], abs=2e-4)    # sRGB primaries' luminance
    assert Y == pytest.approx(lib_Y(rgb[0] / 255), abs=1e-6)
    # grey + alpha over white: black at alpha 128/255 shows sRGB 1 - 128/255
    la = np.zeros((2, 3, 2), np.uint8)
    la[..., 1] = [[0, 128, 255]] * 2
    Image.fromarray(la, mode="LA").save(tmp_path / "la.png")
    Y = picture.read_luminance(tmp_path / "la.png")[0]
    assert Y == pytest.approx(lib_Y(np.repeat([[1.0], [1 - 128 / 255], [0.0]], 3, axis=1)), abs=1e-6)
    rgba = np.array([[[255, 0, 0, 0], [255, 0, 0, 255], [0, 0, 255, 64]]], np.uint8)
    Image.fromarray(rgba, mode="RGBA").save(tmp_path / "rgba.png")
    Y = picture.read_luminance(tmp_path / "rgba.png")[0]
    a = 64 / 255
    assert Y == pytest.approx(lib_Y([[1, 1, 1], [1, 0, 0], [1 - a, 1 - a, 1]]), abs=1e-6)


def test_area_average_is_in_linear_light(tmp_path):
    """A fine black and white pattern looks as bright as Y 0.5 (L* 76), not as sRGB 128 (L* 54)."""
    a = np.indices((16, 16)).sum(axis=0) % 2 * 255
    Image.fromarray(a.astype(np.uint8)).save(tmp_path / "check.png")
    Y = picture.resample(picture.read_luminance(tmp_path / "check.png"), (4, 4))
    assert Y == pytest.approx(np.full((4, 4), 0.5), abs=1e-6)


# --- curves --------------------------------------------------------------------------------------

@pytest.mark.parametrize("curve", tone.CURVES)
@pytest.mark.parametrize("gamma", [0.5, 1.0, 2.2])
@pytest.mark.parametrize("invert", [False, True])
def test_every_curve_is_monotonic_from_min_to_max(curve, gamma, invert):
    Y = np.linspace(0, 1, 1001)
    t = tone.thickness(Y, curve, 0.8, 2.4, 1.5, gamma, invert)
    d = np.diff(t)
    if invert:
        assert np.all(d >= 0) and np.any(d > 0)
        assert (t[0], t[-1]) == pytest.approx((0.8, 2.4))
    else:
        assert np.all(d <= 0) and np.any(d < 0)
        assert (t[0], t[-1]) == pytest.approx((2.4, 0.8))


def wedge(tmp_path):
    codes = np.round(np.arange(16) * 255 / 15).astype(np.uint8)
    Image.fromarray(np.repeat(np.repeat(codes[None], 20, axis=0), 20, axis=1)).save(tmp_path / "wedge.png")
    return tmp_path / "wedge.png", codes


@pytest.mark.parametrize("curve, within", [("perceptual", True), ("linear", False), ("transmission", False)])
def test_wedge_steps_within_one_L(tmp_path, curve, within):
    """16-step grey wedge at the defaults: the perceptual curve puts every step's predicted L*
    within 1 of its target (the grey's L* on the plate's range); the other two do not. Measured on
    the planned thickness and on the thickness as printed (where the gap is narrower than a
    mid-line the walls narrow for a thin one: nothing is snapped)."""
    p, codes = wedge(tmp_path)
    o = lt.LithoOptions(curve=curve, height=2.0)
    plan = lt.plan_lithophane(p, o)
    f = plan.field
    cols = [int(round((i + 0.5) * (len(f.s) - 1) / 16)) for i in range(16)]
    L_lo = tone.lightness(np.exp(-1.5 * 1.6))
    target = L_lo + (100 - L_lo) * lib_L(np.repeat(codes[:, None] / 255, 3, axis=1)) / 100
    for t in (f.t[f.n_foot + 5, cols], lt.printed_thickness(plan)[5, cols]):
        pred = tone.lightness(tone.plate_luminance(t, 1.5, 0.8))
        err = np.abs(pred - target).max()
        assert (err <= 1.0) == within, err


def test_gamma_and_invert_on_the_perceptual_curve():
    """gamma > 1 lightens mid-tones, invert swaps the ends; both on L*."""
    Y = tone.luminance(50.0)                                     # L* 50
    t1 = tone.thickness(Y, "perceptual", 0.8, 2.4, 1.5)
    t2 = tone.thickness(Y, "perceptual", 0.8, 2.4, 1.5, gamma=2.0)
    ti = tone.thickness(Y, "perceptual", 0.8, 2.4, 1.5, invert=True)
    L = lambda t: float(tone.lightness(tone.plate_luminance(t, 1.5, 0.8)))
    L_lo = float(tone.lightness(np.exp(-2.4)))
    assert L(t1) == pytest.approx(L_lo + 0.5 * (100 - L_lo), abs=1e-6)
    assert L(t2) == pytest.approx(L_lo + 0.75 * (100 - L_lo), abs=1e-6)   # darkness 0.5 ** 2
    assert L(ti) == pytest.approx(L(t1), abs=1e-6)                        # L* 50 is its own negative
    Y80 = tone.luminance(80.0)
    assert L(tone.thickness(Y80, "perceptual", 0.8, 2.4, 1.5, invert=True)) == pytest.approx(
        L_lo + 0.2 * (100 - L_lo), abs=1e-6)


# --- the predicted look ---------------------------------------------------------------------------

def test_look_in_L_and_the_png_unstretched(tmp_path):
    from skimage.metrics import structural_similarity

    g = np.tile(np.linspace(0, 255, 60), (24, 1)).astype(np.uint8)      # a grey ramp
    g[:, :6] = 0
    g[:, -6:] = 255
    Image.fromarray(g).save(tmp_path / "ramp.png")
    res = lt.make(tmp_path / "ramp.png", tmp_path / "o", options=lt.LithoOptions(width=30.0, height=6.0))
    lk = json.loads(res.paths["json"].read_text())["look"]
    assert lk["curve"] == "perceptual"
    assert lk["plate_L_range"] == pytest.approx([36.12, 100.0], abs=0.01)
    # no figure compares the model with itself; the picture against the print as sampled (0.4 x
    # 0.2 mm) and blurred by the light's scatter is not the same, and says so
    assert not {"mean_abs_dL", "ssim_L", "correlation"} & set(lk)
    v = lk["picture_vs_print"]
    assert v["sampled_mm"] == [0.4, 0.2] and v["scatter_sigma_mm"] == 0.5
    assert 0.05 < v["mean_abs_dL"] < 5 and 0.3 < v["ssim_L"] < 0.999
    from bulgekit.cli.litho import summary
    assert (f"a model, not a measured print): mean |dL*| {v['mean_abs_dL']:.1f}, SSIM {v['ssim_L']:.2f}"
            in summary(res.stats | {"name": "ramp"}))
    sharp = lt.make(tmp_path / "ramp.png", tmp_path / "o2",
                    options=lt.LithoOptions(width=30.0, height=6.0, pitch=0.8)).stats["look"]["picture_vs_print"]
    assert sharp["mean_abs_dL"] > v["mean_abs_dL"]                 # coarser sampling loses more
    # the backlit panel shows the thickest plate as the grey it is (sRGB of Y = exp(-1.5 x 1.6))
    im = np.asarray(Image.open(res.paths["png"]))
    pw, ph = res.plan.field.picture_mm
    w, top, pad = int(pw * 4), 22, 10
    x2 = pad + w + pad                                            # second panel
    black = im[top + 12, x2 + 6]
    white = im[top + 12, x2 + w - 6]
    assert white == 255
    assert black == pytest.approx(255 * tone.to_srgb(np.exp(-2.4)), abs=2)   # 85, not 0
    assert im[top + 12, x2 + w + pad + 6] <= 2                    # the stretched panel: black


@pytest.mark.parametrize("block_rate", [None, 0], ids=["defaults", "block-rate 0"])
def test_end_columns_print_what_the_picture_says(tmp_path, block_rate):
    """A noisy photo-like picture (planar defaults): the predicted look's first and last two
    columns show the planned thickness, as the columns inside do; the end probes once sat on the
    gap's edge and printed white specks (left) and a white line (right). What the pieces lay
    (their E, laid_area) at the plate's ends is the body's there on every layer, as inside.
    (The look's end columns are the end walls, solid by construction: the laid area is what
    says that the G-code lays them.)"""
    rng = np.random.default_rng(3)
    y, x = np.mgrid[0:60, 0:100]
    g = 128 + 60 * np.sin(x / 9.0) * np.cos(y / 7.0) + rng.normal(0, 12, (60, 100))
    Image.fromarray(np.clip(g, 0, 255).astype(np.uint8)).save(tmp_path / "noisy.png")
    kw = {} if block_rate is None else {"block_rate": block_rate}
    plan = lt.plan_lithophane(tmp_path / "noisy.png", lt.LithoOptions(width=40.0, height=8.0, **kw))
    o = plan.options
    L = lambda t: tone.lightness(tone.plate_luminance(t, o.attenuation, o.min_thickness))
    dL = L(lt.printed_thickness(plan)) - L(plan.field.t[plan.field.n_foot:])
    edges = dL[:, [0, 1, -2, -1]]
    inner = dL[:, 2:-2]
    assert np.abs(edges).max() <= max(2.0, np.abs(inner).max())
    assert np.abs(edges).mean() <= np.abs(inner).mean() + 0.5
    ends, inside = [], []
    for k in range(plan.field.n_foot, len(plan.layers)):
        laid, body = lt.laid_area(plan, k)
        d = np.abs(laid / body - 1)
        ends += [d[0], d[-1]]
        inside.append(d[1:-1])
    assert max(ends) <= 0.03                                     # (measured: 2.2 %, 1.8 %)
    assert np.median(ends) <= 2 * np.median(np.concatenate(inside)) + 0.01
    figures = lt.plan_stats(plan, 1.0)["laid_volume"]
    assert figures["end_intervals_max_dev"] == pytest.approx(max(ends), abs=1e-4)


# --- calibration plate ------------------------------------------------------------------------------

def test_calibration_plate(tmp_path):
    r = CliRunner().invoke(main, ["litho", "--calibration", "-o", str(tmp_path / "cal")])
    assert r.exit_code == 0, r.output
    for ext in (".litho.gcode", ".stock.gcode", ".stl", ".transmission.png", ".litho.json"):
        assert (tmp_path / "cal" / f"calibration{ext}").stat().st_size > 0
    s = json.loads((tmp_path / "cal" / "calibration.litho.json").read_text())
    steps = s["calibration"]["steps"]
    assert len(steps) == 10
    assert [st["thickness_mm"] for st in steps] == pytest.approx(np.round(np.linspace(0.8, 2.4, 10), 2))
    planned = [st["planned_mm"] for st in steps]
    assert planned[0] == 0.8 and planned[-1] == 2.4 and np.all(np.diff(planned) > 0)
    assert "2.40" in r.output and "36.1" in r.output              # the table: thickest step, its L*
    # each label strip carries the digits of its step's planned thickness, raised to --max
    fld, info = lt.calibration_field(lt.LithoOptions(foot=0))
    assert lt.calibration_field(lt.LithoOptions())[0].n_foot > 0           # it stands on a foot
    X, Z = np.meshgrid(fld.s, (np.arange(fld.t.shape[0]) + 0.5) * 0.2)
    labels = [f"{st['planned_mm']:.2f}" for st in info["steps"]]
    for i, ((a0, a1, b0, b1), (c0, c1, d0, d1)) in enumerate(calibration.calibration_layout()):
        step = (X >= a0 + 1) & (X < a1 - 1) & (Z >= b0 + 1) & (Z < b1 - 1)
        assert np.all(fld.t[step] == pytest.approx(planned[i], abs=1e-3))
        strip = (X >= c0) & (X < c1) & (Z >= d0) & (Z < d1)
        ink = strip & (fld.t == 2.4)
        assert 0.1 < ink.sum() / strip.sum() < 0.5
        own = calibration.calibration_map(fld.s, Z[:, 0], fld.t[step][:1].repeat(10), 0.8, 2.4, labels)
        other = calibration.calibration_map(fld.s, Z[:, 0], fld.t[step][:1].repeat(10), 0.8, 2.4,
                                     labels[::-1])                      # another step's digits
        assert np.array_equal(ink, strip & (own == 2.4))
        assert not np.array_equal(ink, strip & (other == 2.4))


@pytest.mark.parametrize("args, message", [
    (["--calibration", "x.png"], "not both"),
    ([], "missing IMAGE"),
    (["--calibration", "--shape", "cylinder"], "--calibration: the calibration plate is planar"),
    (["--calibration", "--width", "50"], "--width does not apply to --calibration"),
    (["--calibration", "--curve", "linear"], "--curve does not apply to --calibration"),
])
def test_calibration_usage(tmp_path, args, message):
    Image.fromarray(np.full((10, 10), 128, np.uint8)).save(tmp_path / "x.png")
    args = [str(tmp_path / a) if a.endswith(".png") else a for a in args]
    r = CliRunner().invoke(main, ["litho", *args, "-o", str(tmp_path / "o")])
    assert r.exit_code != 0 and message in r.output
    assert not (tmp_path / "o").exists()
