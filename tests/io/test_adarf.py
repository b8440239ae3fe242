"""The AdaRF real UHF-RFID reads: loader, conversion to filter steps, and tag localization on them.

Real data (skipped, with the reason, when the data folder is absent): the folder is
``$JAXNAV_DATA/adarf-uhf-rfid-phase``, default ``../shared/data``
(:func:`jaxnav.io.adarf.data_dir`). Reference facts are properties of the data, found
on the raw files without jaxnav (about 1000 reads per tag and aperture point over 8
channels, stray EPCs, phase residual 0.21–0.60 rad at the ground truth against ≈ 1.8 rad
for wrong positions).
"""

from __future__ import annotations

import gzip
import math

import numpy as np
import pytest

from jaxnav.experiments.uhf import real as uhf_real
from jaxnav.io import adarf
from jaxnav.models import uhf_rfid as U

EXPERIMENT = "181218-01-50-8"


@pytest.fixture(scope="module")
def exp():
    try:
        adarf.data_dir()
    except FileNotFoundError as err:
        pytest.skip(f"the AdaRF data are not available (set {adarf.ENV_VAR}): {err}")
    return adarf.load_experiment(EXPERIMENT)


def test_loader_reads_the_documented_format(exp):
    assert EXPERIMENT in adarf.available_experiments()
    # the data hold about 1000 reads per target tag and aperture point, over the 8 channels
    counts = np.zeros((3, adarf.NUM_POINTS), int)
    np.add.at(counts, (exp.tag, exp.point), 1)
    assert 800 < counts.min() and counts.max() < 1300
    assert set(np.unique(exp.channel)) == set(range(8))
    assert exp.num_stray > 0  # the ...0005 tag and stray reads are dropped, and counted
    assert np.all((exp.phase >= 0) & (exp.phase < 2 * math.pi))
    assert np.all((exp.rssi_dbm > -80) & (exp.rssi_dbm < -20))
    # one antenna position per file, 0.02 ... ~1 m in about 0.02 m steps; in this experiment the
    # last two points are both at 0.978 m (a quirk of the data, kept as recorded)
    x = exp.aperture_x
    assert x[0] == pytest.approx(0.02, abs=2e-3) and x[-1] == pytest.approx(1.0, abs=0.03)
    assert np.sum(np.diff(x) > 0.015) >= 47 and np.all(np.diff(x) > -1e-3)
    np.testing.assert_allclose(exp.tags_xy, [[0.30, 0.88], [0.50, 0.88], [0.70, 0.88]])
    assert not exp.phase.flags.writeable


def test_loader_errors(tmp_path, exp):
    with pytest.raises(FileNotFoundError, match="JAXNAV_DATA"):
        adarf.data_dir(tmp_path)
    with pytest.raises(ValueError, match="unknown experiment"):
        adarf.load_experiment("no-such-experiment")
    with pytest.raises(ValueError, match="tag must be 0, 1 or 2"):
        adarf.to_uhf_reads(exp, 3)
    with pytest.raises(ValueError, match="channels"):
        adarf.to_uhf_reads(exp, 0, channels=(8,))
    # a file without the documented columns is refused with its path
    root = tmp_path / adarf.DATASET
    (root / "dataset1_test" / "x").mkdir(parents=True)
    (root / "tag_ground_truth.csv").write_text(
        "experiment,epc,x_m,y_m\n" + "".join(f"x,{e},0.1,0.5\n" for e in adarf.TARGET_EPCS)
    )
    for i in range(adarf.NUM_POINTS):
        with gzip.open(root / "dataset1_test" / "x" / f"{i}.csv.gz", "wt", encoding="utf-8-sig") as fh:
            fh.write("epc,frequency,RSSI\n")
    with pytest.raises(ValueError, match="missing columns"):
        adarf.load_experiment("x", tmp_path)


def test_phase_convention_fits_the_ground_truth(exp):
    """jaxnav's φ = −4πD/λ + θ on the negated reader phase fits each tag at its truth, not 10 cm away."""
    for g in range(3):
        _, rms_true = adarf.phase_residuals(exp, g, exp.tags_xy[g])
        _, rms_off = adarf.phase_residuals(exp, g, exp.tags_xy[g] + np.array([0.10, 0.0]))
        assert rms_true < 0.6 and rms_off > 1.0, (g, rms_true, rms_off)  # the data: 0.21-0.60 vs ~1.8 rad


def test_to_uhf_reads_slots_channels_and_alignment(exp):
    reads = adarf.to_uhf_reads(exp, 1, reads_per_channel=3)
    assert reads.mask.shape == (adarf.NUM_POINTS, 24)
    assert bool(np.all(reads.mask))  # every channel has > 3 reads at every point
    lam = np.asarray(reads.wavelength[0])
    np.testing.assert_allclose(lam, np.repeat(U.SPEED_OF_LIGHT / adarf.CHANNELS_HZ, 3), rtol=1e-6)
    np.testing.assert_allclose(np.asarray(reads.reader[:, 0, 0]), exp.aperture_x, atol=1e-6)
    assert np.all(np.asarray(reads.reader[..., 3]) == np.float32(adarf.BORESIGHT_YAW))

    # aligned channels agree: the circular spread of the 8 channels' mean phases at a point is small,
    # and much larger without the alignment (offsets up to 1.6 rad apart, see channel_offsets)
    def spread(r):
        z = np.exp(1j * np.asarray(r.phase)).reshape(adarf.NUM_POINTS, 8, 3).mean(-1)
        return np.mean(1 - np.abs(z.mean(-1)))

    raw = adarf.to_uhf_reads(exp, 1, reads_per_channel=3, align_channels=False)
    assert spread(reads) < 0.1 < spread(raw)
    # one channel: 50 x reads_per_channel slots at that channel's wavelength
    one = adarf.to_uhf_reads(exp, 1, reads_per_channel=2, channels=(5,), align_channels=False)
    assert one.mask.shape == (adarf.NUM_POINTS, 2)
    np.testing.assert_allclose(np.asarray(one.wavelength), U.SPEED_OF_LIGHT / adarf.CHANNELS_HZ[5], rtol=1e-6)
    # more slots than reads: the rest is masked, not zero-filled reads
    many = adarf.to_uhf_reads(exp, 1, reads_per_channel=400, channels=(0,))
    per_point = np.asarray(many.mask).sum(1)
    counts = np.bincount(exp.point[(exp.tag == 1) & (exp.channel == 0)], minlength=adarf.NUM_POINTS)
    np.testing.assert_array_equal(per_point, np.minimum(counts, 400))


@pytest.fixture(scope="module")
def localized(exp):
    return uhf_real.localize(EXPERIMENT, ("combined", "phase"), seeds=1)


def test_real_tags_are_localized_well_under_the_prior_spread(localized):
    """Combined and phase-only end well inside the search box's spread, for each of the three tags.

    Measured (jaxnav uhf-real --experiment 181218-01-50-8 --seeds 3, 5000 particles, seeds 0-2):
    combined 0.042-0.050 / 0.041-0.042 / 0.236-0.256 m and phase-only 0.173-0.307 / 0.045-0.076 /
    0.211-0.247 m for tags 0 / 1 / 2, against a uniform guess's RMS error of 0.56-0.60 m.
    The bound 0.35 m is the largest of those (0.31 m) plus a margin for platform differences.
    Phase-only fixes the position along the track to a few cm, the depth only weakly.
    """
    assert len(localized) == 6
    for r in localized:
        prior = uhf_real.prior_rmse(r.truth)
        assert prior > 0.55
        assert r.final_error[0] < 0.35, (r.tag, r.weighting, r.final_error)
        assert np.all(np.isfinite(r.estimates))
        if r.weighting == "phase":
            dx = r.estimates[0, -1, 0] - r.truth[0]
            assert abs(dx) < 0.08, (r.tag, dx)  # measured |dx| <= 0.04 m on this experiment (<= 0.07 on all four)
    best = {g: min(r.final_error[0] for r in localized if r.tag == g) for g in range(3)}
    assert max(best.values()) < 0.30, best  # measured (3 seeds): at most 0.05 / 0.04 / 0.25 m


def test_format_and_plot(localized, tmp_path):
    text = uhf_real.format_results(localized)
    assert EXPERIMENT in text and "phase" in text and len(text.splitlines()) == 7
    pytest.importorskip("matplotlib")
    path = tmp_path / "real.png"
    uhf_real.plot_results(localized, str(path))
    assert path.stat().st_size > 10_000


def test_prior_rmse_closed_form_matches_sampling():
    rng = np.random.default_rng(0)
    lo, hi = np.asarray(uhf_real.BOX_LO), np.asarray(uhf_real.BOX_HI)
    pts = lo + rng.random((200_000, 2)) * (hi - lo)
    truth = np.array([0.3, 0.88])
    mc = np.sqrt(np.mean(np.sum((pts - truth) ** 2, axis=1)))
    assert uhf_real.prior_rmse(truth) == pytest.approx(mc, rel=5e-3)  # MC sd of the mean square ~ 0.2 %
