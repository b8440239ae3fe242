"""UHF-RFID reader simulator, light and strong multipath ([A] §4.1.2, §5.2): jaxnav.sim.uhf_reader.

Speed: every simulate_reads call here has the shape (G, T, J) = (2, 50, 200),
light (no images) or strong (17 images), so the file compiles the (slow to
compile) Gamma sampler only twice. Statistical tolerances are 4 standard
errors (or the stated quantiles) of the exact sampling distributions.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import special

from jaxnav.core.weights import wrap_angle
from jaxnav.models import uhf_calibration
from jaxnav.models import uhf_rfid as U
from jaxnav.sim import uhf_reader as R

T, J = 50, 200  # shared shapes: N = T·J = 10 000 reads per tag
N = T * J
LAM = U.A_WAVELENGTH
ANCHOR = np.array([1.0, 1.0, 1.0])
SECOND = np.array([0.4, 2.6, 1.6])  # a second tag so that every call has G = 2 (one compiled shape)
TAGS = np.stack([ANCHOR, SECOND])
# a 2 m pass at y = −0.5 m, z = 1 m facing +y, 1.5 m from ANCHOR at its closest (inside DEFAULT_ROOM)
ANCHOR_LINE = R.line_path([0.0, -0.5, 1.0], [2.0, -0.5, 1.0], T, facing=ANCHOR)
# [A] Fig. 5.2: a straight pass, 1 cm steps, 2 m in front of a tag (shared by the noise-free tests)
PASS_TAG = np.array([1.0, 1.5, 1.0])
PASS = R.line_path([0.0, -0.5, 1.0], [2.0, -0.5, 1.0], 201, facing=PASS_TAG)


def _wrapped(x):
    return np.asarray(wrap_angle(jnp.asarray(x)), np.float64)


def _gamma_moment(k, th, n):
    """E[g^n] = θ^n Γ(k+n)/Γ(k) for g ~ Gamma(k, θ)."""
    return th**n * math.exp(math.lgamma(k + n) - math.lgamma(k))


def _local_maxima(x):
    """Number of strict local maxima of a sequence after merging runs of equal values (plateaus)."""
    x = np.asarray(x, np.float64)
    keep = np.concatenate([[True], np.diff(x) != 0])
    v = x[keep]
    return int(np.sum((v[1:-1] > v[:-2]) & (v[1:-1] > v[2:])))


def _ks_gamma(u, k, th):
    """Kolmogorov–Smirnov distance between the sample u and Gamma(k, θ)."""
    u = np.sort(np.asarray(u, np.float64))
    n = u.size
    cdf = special.gammainc(float(k), u / float(th))
    i = np.arange(1, n + 1)
    return max(np.max(i / n - cdf), np.max(cdf - (i - 1) / n))


@pytest.fixture(scope="module")
def anchor_reads():
    """Light and strong reads of ANCHOR along ANCHOR_LINE (same key), shape (T, J).

    Both sensitivities are 0 here (every read kept), so that the fits see the untruncated
    distributions: the misfit measured under strong multipath is the walls' alone.
    """
    key = jax.random.PRNGKey(20240601)
    kw = dict(reads_per_step=J, sensitivity=0.0, tag_sensitivity=0.0)
    light = R.simulate_reads(key, ANCHOR_LINE, TAGS, multipath="light", **kw)
    strong = R.simulate_reads(key, ANCHOR_LINE, TAGS, multipath="strong", **kw)
    return jax.tree_util.tree_map(lambda x: x[0], light), jax.tree_util.tree_map(lambda x: x[0], strong)


# ----------------------------------------------------------------------------- paths


def test_line_path_ends_spacing_and_heading():
    tag = np.array([1.0, 2.0, 0.5])
    p = R.line_path([0.0, 0.0], [2.0, 0.0], 21, facing=tag)
    assert p.shape == (21, 4) and p.dtype == np.float32
    np.testing.assert_allclose(p[0, :3], [0.0, 0.0, R.DEFAULT_READER_HEIGHT])
    np.testing.assert_allclose(p[-1, :3], [2.0, 0.0, R.DEFAULT_READER_HEIGHT])
    np.testing.assert_allclose(np.diff(p[:, 0]), 0.1, atol=1e-6)
    np.testing.assert_allclose(p[:, 3], math.pi / 2, atol=1e-6)  # tag on the left (+y): face +y
    q = R.line_path([0.0, 0.0, 0.4], [2.0, 0.0, 0.4], 5, facing=[1.0, -2.0])
    np.testing.assert_allclose(q[:, 3], -math.pi / 2, atol=1e-6)  # tag on the right: face −y
    np.testing.assert_allclose(q[:, 2], 0.4)
    # the boresight really points at the tag's side: the closest pose sees the tag in the main lobe
    mid = p[10]
    assert float(U.off_boresight_angle(tag - mid[:3], mid[3])) < U.DEFAULT_ANTENNA.phi_s
    np.testing.assert_allclose(R.line_path([0, 0], [0, 1], 3)[:, 3], math.pi, atol=1e-6)  # default: left of travel
    np.testing.assert_allclose(R.line_path([0, 0], [1, 0], 3, heading=0.3)[:, 3], 0.3, atol=1e-6)


def test_lawnmower_covers_offsets_and_makes_3d_observable():
    p = R.lawnmower_path((0.0, 2.0), [-0.5, -0.2], [0.5, 1.5], 41)
    assert p.shape[1] == 4 and p.shape[0] >= 4 * 41
    np.testing.assert_allclose(p[:, 3], math.pi / 2, atol=1e-6)
    offsets = {(round(float(y), 3), round(float(z), 3)) for y, z in p[:, 1:3]}
    assert {(-0.5, 0.5), (-0.2, 0.5), (-0.5, 1.5), (-0.2, 1.5)} <= offsets
    step = np.linalg.norm(np.diff(p[:, :3], axis=0), axis=1)
    assert step.max() <= 0.05 + 1e-6  # connectors sampled at the pass spacing 2/40 m: no jumps
    assert R.lawnmower_path((0.0, 2.0), [-0.5, -0.2], [0.5, 1.5], 41, connect=False).shape == (4 * 41, 4)

    # Observability (module docstring): the Jacobian of the reader-tag distances w.r.t. the tag
    # position has a null direction for a single line (rotation about the line) and full rank
    # for passes with non-collinear (y, z) offsets.
    tag = jnp.array([1.1, 1.3, 0.9])

    def dists(x, path):
        return jnp.linalg.norm(x - jnp.asarray(path)[:, :3], axis=-1)

    line = R.line_path([0.0, -0.5, 1.0], [2.0, -0.5, 1.0], 41, heading=math.pi / 2)
    s_line = np.linalg.svd(np.asarray(jax.jacfwd(dists)(tag, line)), compute_uv=False)
    s_mow = np.linalg.svd(np.asarray(jax.jacfwd(dists)(tag, p)), compute_uv=False)
    assert s_line[-1] < 1e-5 * s_line[0]  # rank 2: a circle of tag positions fits a line
    assert s_mow[-1] > 0.1 * s_mow[0]  # well conditioned in all three directions
    # the same with only the range *differences* (phase with an unknown offset): drop the mean
    jd = np.asarray(jax.jacfwd(dists)(tag, p))
    assert np.linalg.svd(jd - jd.mean(0), compute_uv=False)[-1] > 0.05 * s_mow[0]


def test_anchor_position_distance_direction_and_box():
    tag = np.array([1.0, 1.5, 1.0])
    q = R.anchor_position(tag, 0.05, direction=[0.0, 3.0, 0.0])
    np.testing.assert_allclose(q, [1.0, 1.55, 1.0])
    box = R.SEARCH_BOX_A
    for d in (0.0, LAM / 4, LAM / 2, LAM, 0.5):
        q1 = R.anchor_position(tag, d, key=jax.random.PRNGKey(3), box=box)
        q2 = R.anchor_position(tag, d, key=jax.random.PRNGKey(3), box=box)
        np.testing.assert_array_equal(q1, q2)  # same key, same point
        np.testing.assert_allclose(np.linalg.norm(q1 - tag), d, atol=1e-6)
        assert np.all(q1 >= box[0]) and np.all(q1 <= box[1])
    corner = np.array([0.05, 0.05, 0.05])  # only one octant of directions stays inside
    q = R.anchor_position(corner, 0.3, key=jax.random.PRNGKey(0), box=box)
    assert np.all(q >= 0) and abs(np.linalg.norm(q - corner) - 0.3) < 1e-6
    with pytest.raises(ValueError, match="outside"):
        R.anchor_position(tag, 0.5, direction=[0.0, 0.0, 1.0], box=(np.zeros(3), np.array([2.0, 3.0, 1.2])))
    with pytest.raises(ValueError, match="exactly one"):
        R.anchor_position(tag, 0.1)
    with pytest.raises(ValueError, match="inside the box"):
        R.anchor_position(tag, 5.0, key=jax.random.PRNGKey(0), box=box)


# ----------------------------------------------------------------------------- light multipath


def test_light_rssi_mean_and_phase_match_the_model(getkey):
    """At a fixed pose the reads are the model's: E[y] = a·k(k+1)θ², phase = model phase + N(0, σ²)."""
    mp = R.LIGHT_MULTIPATH
    k, th = mp.gamma
    pose = np.array([1.2, 0.4, 0.8, math.pi / 2], np.float32)
    path = np.tile(pose, (T, 1))
    off = 1.234
    reads = R.simulate_reads(getkey(), path, TAGS, np.array([off, 0.0]), multipath="light", reads_per_step=J)
    U.validate_reads(reads)
    reads = jax.tree_util.tree_map(lambda x: x[0], reads)
    assert bool(reads.mask.all())  # 0.7 m away in the main lobe: P_inc ≈ +0 dBm ≫ −18 dBm
    y = np.asarray(reads.rssi, np.float64).ravel()
    a = float(U.power_scale(pose, ANCHOR))
    m2, m4 = _gamma_moment(k, th, 2), _gamma_moment(k, th, 4)
    mean = a * m2
    np.testing.assert_allclose(mean, float(U.mean_power(pose, ANCHOR, U.DEFAULT_CHANNEL, mp.gamma)), rtol=1e-5)
    se = a * math.sqrt(m4 - m2 * m2) / math.sqrt(N)  # exact sd of y = a·g² over √N
    assert abs(y.mean() - mean) < 4.0 * se, (y.mean(), mean, se)
    # the normalised u = √(y/a) has the Gamma's variance kθ² (4 standard errors of a sample variance)
    u = np.sqrt(y / a)
    # Var(s²) ≈ (μ₄ − σ⁴)/N with the Gamma's central μ₄ = 3k(k+2)θ⁴ and σ⁴ = k²θ⁴
    var_se = th * th * math.sqrt((2 * k * k + 6 * k) / N)
    assert abs(u.var() - k * th * th) < 4.0 * var_se
    # phase: wrapped difference to the model's phase is N(0, σ²)
    dist = float(np.linalg.norm(ANCHOR - pose[:3]))
    d = _wrapped(np.asarray(reads.phase, np.float64).ravel() - float(U.phase(dist, LAM, off)))
    sig = mp.phase_sigma
    assert abs(d.mean()) < 4.0 * sig / math.sqrt(N)
    assert abs(d.std() - sig) < 4.0 * sig / math.sqrt(2 * N)
    assert np.all((np.asarray(reads.phase) >= 0) & (np.asarray(reads.phase) < 2 * math.pi))


def test_anchor_reads_recover_light_gamma_parameters(anchor_reads):
    """estimate_gamma on the anchor's reads (a from anchor_power_scale) recovers (k, θ) of the light preset."""
    light, _ = anchor_reads
    k, th = R.LIGHT_MULTIPATH.gamma
    a = R.anchor_power_scale(light, ANCHOR)
    np.testing.assert_allclose(a, U.power_scale(light.reader, ANCHOR, wavelength=light.wavelength), rtol=1e-6)
    mask = np.asarray(light.mask).ravel()
    assert mask.sum() == N  # sensitivities 0 (fixture): every read kept
    fit = uhf_calibration.estimate_gamma(np.asarray(light.rssi).ravel(), np.asarray(a).ravel(), mask)
    assert not bool(fit.used_default)
    # sampling sd of the ML k̂: √(k / (N (k ψ′(k) − 1))) (Fisher information of the Gamma); ū = k̂θ̂ has sd √(k θ² / N)
    sd_k = math.sqrt(k / (N * (k * float(special.polygamma(1, k)) - 1.0)))
    sd_mean = math.sqrt(k * th * th / N)
    k_hat, th_hat = float(fit.params.k), float(fit.params.theta)
    print(f"light anchor fit: k̂ = {k_hat:.3f} (k = {k}, sd {sd_k:.3f}), θ̂ = {th_hat:.5f} (θ = {th})")
    assert abs(k_hat - k) < 4.0 * sd_k
    assert abs(k_hat * th_hat - k * th) < 4.0 * sd_mean


# ----------------------------------------------------------------------------- strong multipath


def test_no_walls_reduces_exactly_to_the_light_model(getkey):
    """Γ = 0: h_mp = 1 exactly (second-order image code run), and the reads equal the light model's."""
    mp0 = R.STRONG_MULTIPATH._replace(room=R.STRONG_MULTIPATH.room._replace(reflection=np.zeros(5, np.float32)))
    seqs = R.image_sequences(2)
    assert len(seqs) == 17
    re, im, dist = jax.jit(R.multipath_gain, static_argnames=("seqs", "softness"))(
        jnp.asarray(PASS),
        jnp.asarray(PASS_TAG, jnp.float32),
        jnp.float32(LAM),
        U.DEFAULT_ANTENNA,
        jax.tree_util.tree_map(jnp.asarray, mp0.room),
        seqs,
        None,
    )
    np.testing.assert_array_equal(np.asarray(re), 1.0)
    np.testing.assert_array_equal(np.asarray(im), 0.0)
    cc = R.composite_channel(PASS, PASS_TAG, mp0)
    np.testing.assert_array_equal(np.asarray(cc.power_ratio), 1.0)
    np.testing.assert_array_equal(np.asarray(cc.phase_shift), 0.0)
    # expected RSSI: the model's mean power
    np.testing.assert_allclose(
        R.expected_rssi(PASS, PASS_TAG, mp0),
        U.mean_power(PASS, PASS_TAG, U.DEFAULT_CHANNEL, mp0.gamma),
        rtol=1e-6,
    )
    # reads: a light preset with the strong preset's (k, θ, σ_φ) and the same key gives the same reads
    light_same = R.LIGHT_MULTIPATH._replace(gamma=mp0.gamma, phase_sigma=mp0.phase_sigma)
    key = getkey()
    r0 = R.simulate_reads(key, ANCHOR_LINE, TAGS, multipath=mp0, reads_per_step=J)
    r1 = R.simulate_reads(key, ANCHOR_LINE, TAGS, multipath=light_same, reads_per_step=J)
    for f0, f1 in zip(r0, r1):
        np.testing.assert_array_equal(np.asarray(f0), np.asarray(f1))
    # negative control: with the walls the reads differ
    r2 = R.simulate_reads(key, ANCHOR_LINE, TAGS, multipath="strong", reads_per_step=J)
    assert not np.allclose(np.asarray(r2.rssi), np.asarray(r1.rssi))


def test_strong_multipath_rssi_is_multimodal_along_a_line():
    """[A] Fig. 5.2: the RSSI along a straight pass is unimodal under light multipath, multimodal under strong."""
    tag, line = PASS_TAG, PASS
    light = 10 * np.log10(np.asarray(R.expected_rssi(line, tag, "light")))
    strong = 10 * np.log10(np.asarray(R.expected_rssi(line, tag, "strong")))
    n_light, n_strong = _local_maxima(light), _local_maxima(strong)
    cc = R.composite_channel(line, tag, "strong")
    fade_db = 20 * np.log10(np.asarray(cc.power_ratio))  # |h_mp|⁴ in dB
    print(
        f"local maxima: light {n_light}, strong {n_strong}; |h_mp|^4 from {fade_db.min():.1f} to {fade_db.max():.1f} dB"
    )
    assert n_light == 1
    assert n_strong >= 3
    assert fade_db.max() - fade_db.min() > 10.0  # fading dips: more than 10 dB of wall ripple
    # the composite phase deviates from the direct-path phase, but far less than a cycle on average
    dev = np.abs(np.asarray(cc.phase_shift))
    assert dev.max() > 0.1 and np.sqrt(np.mean(dev**2)) < 1.5


def test_squared_gamma_is_misspecified_under_strong_multipath(anchor_reads):
    """Fit (k, θ) on the anchor's reads (exact ML); the fitted squared-Gamma model describes the light
    reads and fails on the strong ones, by two measures:

    * KS distance of u = √(y/a) to the fitted Gamma (1 % critical value 1.63/√N, conservative with
      fitted parameters);
    * dispersion of the per-pose means ū_t of the J reads at each pose: under the model (i.i.d.
      Gamma whatever the pose) S = Σ_t J (ū_t − ū)² / (k̂θ̂²) ~ χ²_{T−1}; the walls make the mean
      depend on the pose.
    """
    from scipy import stats

    res = {}
    for name, reads in zip(("light", "strong"), anchor_reads):
        y = np.asarray(reads.rssi, np.float64)
        a = np.asarray(R.anchor_power_scale(reads, ANCHOR), np.float64)
        fit = uhf_calibration.estimate_gamma(y.ravel(), a.ravel(), method="ml")
        k, th = float(fit.params.k), float(fit.params.theta)
        u = np.sqrt(y / a)
        s_disp = float(np.sum(J * (u.mean(axis=1) - u.mean()) ** 2) / (k * th * th))
        res[name] = (k, th, _ks_gamma(u.ravel(), k, th), s_disp / (T - 1))
    crit = 1.63 / math.sqrt(N)
    chi_hi = stats.chi2.ppf(0.999, T - 1) / (T - 1)
    print(f"(k̂, θ̂, KS, S/(T−1)): {res}; KS 1% critical {crit:.4f}, χ² 99.9% {chi_hi:.2f}")
    assert res["light"][2] < crit
    assert res["strong"][2] > 3.0 * crit
    assert res["light"][3] < chi_hi
    assert res["strong"][3] > 10.0 * chi_hi
    assert res["strong"][0] < res["light"][0] / 2  # the walls' ripple reads as a much heavier fading (smaller k)


def test_gradients_are_finite_and_walls_matter():
    tag = jnp.array([1.0, 1.5, 1.0])
    line = R.line_path([0.0, -0.5, 1.0], [2.0, -0.5, 1.0], 64, facing=np.asarray(tag))

    def f(tag, refl):
        mp = R.STRONG_MULTIPATH._replace(room=R.STRONG_MULTIPATH.room._replace(reflection=refl))
        return jnp.sum(jnp.log(R.expected_rssi(line, tag, mp)))

    vg = jax.jit(jax.value_and_grad(f, argnums=(0, 1)))  # one compilation for the gradient and the differences
    _, (g_tag, g_refl) = vg(tag, jnp.asarray(R.DEFAULT_ROOM.reflection))

    def f(tag, refl):  # noqa: F811 (the value only)
        return vg(tag, refl)[0]

    assert np.all(np.isfinite(np.asarray(g_tag))) and np.all(np.isfinite(np.asarray(g_refl)))
    assert np.abs(np.asarray(g_refl)).max() > 0
    # central finite difference of the y_hi wall coefficient agrees with the gradient
    e = np.zeros(5, np.float32)
    e[3] = 1e-2
    r0 = np.asarray(R.DEFAULT_ROOM.reflection)
    fd = (f(tag, jnp.asarray(r0 + e)) - f(tag, jnp.asarray(r0 - e))) / 2e-2
    np.testing.assert_allclose(float(g_refl[3]), float(fd), rtol=2e-2)


# ----------------------------------------------------------------------------- reads: shapes, masks, keys


def _two_tag_path():
    return R.line_path([0.0, 0.5, 1.0], [2.0, 0.5, 1.0], T, heading=math.pi / 2)


def test_output_shapes_masks_and_hopping(getkey):
    """Tag in front (≤ 1.9 m) always read; tag 2.5 m behind (back lobe) never: forward link below −18 dBm."""
    tags = np.array([[1.0, 2.0, 1.0], [1.0, -2.0, 1.0]])
    lams = np.array([0.170, 0.173, 0.176])
    reads = R.simulate_reads(
        getkey(), _two_tag_path(), tags, np.array([0.3, 4.0]), multipath="light", reads_per_step=J, wavelengths=lams
    )
    U.validate_reads(reads)
    assert reads.reader.shape == (2, T, J, 4)
    for f in (reads.rssi, reads.phase, reads.wavelength, reads.mask):
        assert f.shape == (2, T, J)
    assert reads.mask.dtype == jnp.bool_
    m = np.asarray(reads.mask)
    # front: P_inc ≥ −12.2 dBm·g (side lobe at 1.9 m) and g ≥ 0.4 except w.p. < 1e-4 (Gamma(20, 0.05) quantile)
    assert m[0].mean() > 0.999
    assert not m[1].any()  # back lobe at ≥ 2.5 m: P_inc ≤ −25 dBm·g, g < 5 always
    # masked slots: the documented finite dummies, never zeros
    np.testing.assert_array_equal(np.asarray(reads.rssi)[1], R.MASKED_RSSI)
    np.testing.assert_array_equal(np.asarray(reads.phase)[1], R.MASKED_PHASE)
    # channel hopping: step t uses λ[t mod 3]; the phase follows that λ
    want = lams[np.arange(T) % 3]
    np.testing.assert_allclose(np.asarray(reads.wavelength)[0], np.broadcast_to(want[:, None], (T, J)), rtol=1e-6)
    path = _two_tag_path()
    dist = np.linalg.norm(tags[0] - path[:, :3], axis=1)
    pred = np.asarray(U.phase(dist, want, 0.3))
    d = _wrapped(np.asarray(reads.phase)[0] - pred[:, None])[m[0]]
    assert np.abs(d).max() < 6 * R.LIGHT_MULTIPATH.phase_sigma
    # with the wrong λ the phases do not match (negative control)
    d_wrong = _wrapped(np.asarray(reads.phase)[0] - np.asarray(U.phase(dist, LAM, 0.3))[:, None])[m[0]]
    assert np.abs(d_wrong).max() > 1.0
    np.testing.assert_array_equal(np.asarray(reads.reader)[0, :, 0], path)


def test_too_far_and_read_probability_mask_reads(getkey):
    path = _two_tag_path()
    tags = np.array([[1.0, 2.0, 1.0], [1.0, 30.0, 1.0]])  # the second 29.5 m away: beyond the ≈ 11 m range
    reads = R.simulate_reads(getkey(), path, tags, multipath="light", reads_per_step=J, read_probability=0.5)
    m = np.asarray(reads.mask)
    assert not m[1].any()
    # Bernoulli(0.5) on top of a tag that is always powered: fraction within 4 binomial sd
    assert abs(m[0].mean() - 0.5) < 4 * math.sqrt(0.25 / N)
    # reader sensitivity above every read masks everything
    none = R.simulate_reads(getkey(), path, tags, multipath="light", reads_per_step=J, sensitivity=1.0)
    assert not np.asarray(none.mask).any()
    U.validate_reads(none)


def test_a_tags_reads_do_not_depend_on_the_other_tags(getkey):
    path = _two_tag_path()
    tags = np.array([[0.4, 1.8, 0.6], [1.5, 2.2, 1.4]])
    off = np.array([0.5, 2.5])
    key = getkey()
    both = R.simulate_reads(key, path, tags, off, multipath="light", reads_per_step=J)
    # the other tag moved and given another offset: tag 1's reads are unchanged
    moved = R.simulate_reads(
        key, path, np.array([[1.9, 2.9, 0.2], tags[1]]), np.array([-1.0, 2.5]), multipath="light", reads_per_step=J
    )
    # the order reversed, with the ids following the tags
    swapped = R.simulate_reads(
        key, path, tags[::-1], off[::-1], multipath="light", reads_per_step=J, tag_ids=np.array([1, 0])
    )
    for fb, fm, fs in zip(both, moved, swapped):
        np.testing.assert_array_equal(np.asarray(fb)[1], np.asarray(fm)[1])
        np.testing.assert_array_equal(np.asarray(fb)[1], np.asarray(fs)[0])
        np.testing.assert_array_equal(np.asarray(fb)[0], np.asarray(fs)[1])
    # negative control: reversed without ids, the keys follow the slots, so the reads differ
    other = R.simulate_reads(key, path, tags[::-1], off[::-1], multipath="light", reads_per_step=J)
    assert not np.array_equal(np.asarray(other.rssi)[0], np.asarray(both.rssi)[1])


# ----------------------------------------------------------------------------- bad inputs


def test_bad_inputs_are_refused():
    key = jax.random.PRNGKey(0)
    path = _two_tag_path()
    tag = np.array([[1.0, 2.0, 1.0]])
    with pytest.raises(ValueError, match="path"):
        R.simulate_reads(key, path[:, :3], tag)
    with pytest.raises(ValueError, match="path z"):
        R.simulate_reads(key, path * np.array([1, 1, -1, 1], np.float32), tag)
    with pytest.raises(ValueError, match="tags"):
        R.simulate_reads(key, path, tag[:, :2])
    with pytest.raises(ValueError, match="below the ground"):
        R.simulate_reads(key, path, np.array([[1.0, 2.0, -0.1]]))
    with pytest.raises(ValueError, match="tags"):
        R.simulate_reads(key, path, np.array([[1.0, np.nan, 1.0]]))
    with pytest.raises(ValueError, match="wavelength"):
        R.simulate_reads(key, path, tag, wavelengths=np.array([0.17, -0.1]))
    with pytest.raises(ValueError, match="wavelength"):
        R.simulate_reads(key, path, tag, wavelengths=0.0)
    with pytest.raises(ValueError, match="multipath"):
        R.simulate_reads(key, path, tag, multipath="medium")
    with pytest.raises(ValueError, match="theta_offset"):
        R.simulate_reads(key, path, tag, theta_offset=np.zeros(2))
    with pytest.raises(ValueError, match="reads_per_step"):
        R.simulate_reads(key, path, tag, reads_per_step=0)
    with pytest.raises(ValueError, match="read_probability"):
        R.simulate_reads(key, path, tag, read_probability=1.5)
    with pytest.raises(ValueError, match="sensitivity"):
        R.simulate_reads(key, path, tag, sensitivity=-1.0)
    with pytest.raises(ValueError, match="order"):
        R.simulate_reads(key, path, tag, multipath="strong", order=3)
    with pytest.raises(ValueError, match="inside the room"):
        R.simulate_reads(key, path, np.array([[1.0, 5.0, 1.0]]), multipath="strong")
    with pytest.raises(ValueError, match="tag_ids"):
        R.simulate_reads(key, path, tag, tag_ids=np.array([0.5]))
    bad_room = R.STRONG_MULTIPATH._replace(room=R.DEFAULT_ROOM._replace(reflection=np.full(5, 1.5, np.float32)))
    with pytest.raises(ValueError, match="reflection"):
        R.simulate_reads(key, path, tag, multipath=bad_room)
    with pytest.raises(ValueError, match="floor"):
        R.get_multipath(R.STRONG_MULTIPATH._replace(room=R.DEFAULT_ROOM._replace(lo=np.array([-1.0, -1.0, 0.5]))))
    with pytest.raises(ValueError, match="k"):
        R.get_multipath(R.LIGHT_MULTIPATH._replace(gamma=U.GammaParams(0.0, 1.0)))
    with pytest.raises(ValueError, match="num_steps"):
        R.line_path([0, 0], [1, 0], 1)
    with pytest.raises(ValueError, match="same"):
        R.line_path([0, 0, 0], [0, 0, 1], 3)
    with pytest.raises(ValueError, match="z_values"):
        R.lawnmower_path((0, 1), [0.0], [-1.0], 5)
    with pytest.raises(ValueError, match="x_range"):
        R.lawnmower_path((1, 1), [0.0], [1.0], 5)
