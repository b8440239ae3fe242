"""IR receiver simulator ([W] §5.1–5.2): physics, OOK waveform, FFT decoding, calibration sweep."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnav.models import ir
from jaxnav.sim import ir_receiver as rx
from jaxnav.sim import ir_world

W = ir.W_VOLTAGE_MODEL
CFG = rx.DEFAULT_CONFIG


@pytest.fixture(scope="module")
def params():
    return rx.default_params()


@pytest.fixture(scope="module")
def sim():
    """Batched windows: ``(keys [B], poses [B, 3], layout, params) -> (waveforms, IRDetection)``.

    One jitted function for every test (it compiles once per emitter count E).
    """

    def one(key, pose, layout, params):
        w = rx.sample_waveform(key, pose, layout, params, CFG)
        return w, rx.decode(w, params, CFG, layout)

    return jax.jit(jax.vmap(one, in_axes=(0, 0, None, None)))


_volts = jax.jit(jax.vmap(rx.received_voltage, in_axes=(0, None, None)))  # [B, R, E]


def _keys(seed, n):
    return jax.random.split(jax.random.PRNGKey(seed), n)


def _poses_at(rx_index, targets, headings, params):
    """Poses that put receiver ``rx_index`` at world points ``targets [B, 2]``."""
    off = np.asarray(params.offsets, np.float64)[rx_index]
    c, s = np.cos(headings), np.sin(headings)
    shift = np.stack([c * off[0] - s * off[1], s * off[0] + c * off[1]], axis=1)
    return jnp.asarray(np.concatenate([targets - shift, headings[:, None]], axis=1), jnp.float32)


def _amplitude_np(e_d, params, height=None):
    """The module's physics re-derived in float64 NumPy: Lambertian LED, inverse square, cosines."""
    h = float(params.height if height is None else height)
    m = float(params.lambertian_order)
    i0 = float(params.gain) * float(params.led_power) * (m + 1) / (2 * np.pi)
    d2 = h * h + np.asarray(e_d, np.float64) ** 2
    return i0 * (h / np.sqrt(d2)) ** m * (h / np.sqrt(d2)) / d2


def _receiver_xy(poses, params):
    return np.asarray(jax.vmap(ir.receiver_positions, in_axes=(0, None))(poses, params.offsets), np.float64)


# ----------------------------------------------------------------------------- physics


def test_calibrated_level_is_close_to_eq_5_3(params):
    layout = ir.make_layout([[0.0, 0.0]], [1])
    e = np.arange(0.0, 0.2805, 0.005)
    poses = _poses_at(0, np.stack([e, np.zeros_like(e)], 1), np.zeros_like(e), params)
    v = np.asarray(_volts(poses, layout, params))[:, 0, 0]
    vw = np.asarray(ir.expected_voltage(W, e))
    # the calibration stated in the module docstring: RMS 0.023 V, max 0.085 V over 0-280 mm
    assert np.sqrt(np.mean((v - vw) ** 2)) < 0.03
    assert np.max(np.abs(v - vw)) < 0.09
    # V = 0 at the closed-form detection range, close to [W]'s 280 mm
    r = float(rx.detection_range(params))
    assert 0.275 < r < 0.29
    pose_r = _poses_at(0, np.array([[r, 0.0]]), np.zeros(1), params)[0]
    assert abs(float(rx.received_voltage(pose_r, layout, params)[0, 0])) < 1e-3
    # the level is the front end applied to the Lambertian / inverse-square amplitude
    a = _amplitude_np(e, params)
    np.testing.assert_allclose(
        v, float(params.v_sat) * np.tanh(a / float(params.v_sat)) - float(params.v_offset), atol=2e-5
    )
    # a height change moves the curve (what Table 5.3 is about): higher -> weaker
    v0 = [float(_volts(poses[:1], layout, params._replace(height=jnp.float32(h)))[0, 0, 0]) for h in (1.1, 1.2, 1.3)]
    assert v0[0] > v0[1] > v0[2] and v0[0] - v0[2] > 0.3


def test_waveform_is_an_ook_square_wave_and_reads_back_exactly(params, sim):
    layout = ir.make_layout([[0.0, 0.0]], [2])  # 150 Hz
    quiet = params._replace(noise_sd=jnp.float32(0.0))
    b = 32  # the batch size of the next test: one compilation serves both
    poses = _poses_at(0, np.tile([[0.0, 0.0], [0.1, 0.05]], (b // 2, 1)), np.tile([0.0, 1.0], b // 2), params)
    w, det = sim(_keys(1, b), poses, layout, quiet)
    xy = _receiver_xy(poses, params)
    a_true = _amplitude_np(np.linalg.norm(xy, axis=-1), params)  # [B, R]
    w = np.asarray(w, np.float64)
    # DC level = duty · amplitude; samples sit at the two OOK levels except near the edges (Gibbs)
    np.testing.assert_allclose(w.mean(-1), 0.5 * a_true, rtol=2e-4)
    near = np.minimum(np.abs(w), np.abs(w - a_true[..., None])) < 0.1 * a_true[..., None]
    assert near.mean() > 0.85
    # the FFT estimate is exact without noise; no harmonic leaks into another code bin
    amp = np.asarray(det.amplitude, np.float64)
    np.testing.assert_allclose(amp[..., 1], a_true, rtol=2e-4)
    assert np.max(np.delete(amp, 1, axis=-1)) < 1e-4 * a_true.max()
    # ... although the square wave's 3rd harmonic (450 Hz, bin 9) is there, at 1/3
    spec = np.abs(np.fft.rfft(w, axis=-1))
    np.testing.assert_allclose(spec[..., 9] / spec[..., 3], 1.0 / 3.0, rtol=1e-3)
    assert bool(np.all(det.valid)) and np.all(np.asarray(det.mask) == ir.to_mask(2))


# ----------------------------------------------------------------------------- decoding


def _emitter_types():
    sets = {(c,) for c in ir.CODES}
    for lay in (ir_world.experiment_layout(), ir_world.unique11_layout(), ir.lattice_layout()):
        sets |= {ir.from_mask(int(m)) for m in np.asarray(lay.masks)}
    sets |= {(1, 2, 3), (4, 7, 9), (2, 5, 8, 9), (1, 3, 5, 7, 9), tuple(ir.CODES)}
    return sorted(sets, key=lambda s: (len(s), s))


def test_fft_decodes_every_emitter_type_across_the_detection_range(params, sim):
    rng = np.random.default_rng(7)
    r_det = float(rx.detection_range(params))
    types = _emitter_types()
    assert len(types) > 30
    n_in, n_out, n_edge = 16, 8, 8
    counts = dict(inside=0, beyond=0, edge_valid=0, wrong=0)
    for t, codes in enumerate(types):
        layout = ir.make_layout([[0.0, 0.0]], [codes])
        e = np.concatenate(
            [
                np.linspace(0.0, 0.26, n_in),  # inside the range (~0.283 m)
                rng.uniform(0.26, 0.305, n_edge),  # the edge: detection or not, never wrong
                rng.uniform(0.305, 0.9, n_out),  # beyond
            ]
        )
        bearing = rng.uniform(-np.pi, np.pi, e.size)
        targets = np.stack([e * np.cos(bearing), e * np.sin(bearing)], 1)
        poses = _poses_at(0, targets, rng.uniform(-np.pi, np.pi, e.size), params)
        _, det = sim(_keys(100 + t, e.size), poses, layout, params)
        valid = np.asarray(det.valid)
        mask = np.asarray(det.mask)
        want = ir.to_mask(codes)
        assert valid[:n_in, 0].all() and (mask[:n_in, 0] == want).all(), (codes, valid[:n_in, 0])
        assert not valid[n_in + n_edge :, 0].any(), codes
        counts["inside"] += n_in
        counts["beyond"] += n_out
        counts["edge_valid"] += int(valid[n_in : n_in + n_edge, 0].sum())
        # receiver 1 is elsewhere: whatever it reports, it is never a wrong ID
        counts["wrong"] += int(np.sum(valid & (mask != want)))
        # the reported level is the noise-free V within the estimator's noise
        v_true = np.asarray(_volts(poses, layout, params))[:, 0, 0]
        assert np.all(np.abs(np.asarray(det.voltage)[:n_in, 0] - v_true[:n_in]) < 5 * 0.0785)
    assert counts["wrong"] == 0, counts
    assert 0 < counts["edge_valid"] < n_edge * len(types)  # the edge band really is an edge
    assert r_det > 0.26


def _random_windows(layout, params, sim, seed, n=1500):
    pos = np.asarray(layout.positions, np.float64)
    lo, hi = pos.min(0) - 0.4, pos.max(0) + 0.4
    rng = np.random.default_rng(seed)
    poses = jnp.asarray(
        np.concatenate([rng.uniform(lo, hi, (n, 2)), rng.uniform(-np.pi, np.pi, (n, 1))], 1), jnp.float32
    )
    _, det = sim(_keys(seed, n), poses, layout, params)
    xy = _receiver_xy(poses, params)  # [n, R, 2]
    d = np.linalg.norm(xy[:, :, None, :] - pos[None, None], axis=-1)  # [n, R, E]
    nearest = np.argmin(d, axis=-1)
    masks = np.asarray(layout.masks)
    # which windows are decodable whatever the LED phases: per code, the nearest emitter's amplitude
    # a1 against the worst case of the others' amplitudes summed at that code (5 noise sd margin)
    amp = _amplitude_np(d, params)  # [n, R, E]
    bits = np.asarray(ir.mask_bits(jnp.asarray(masks)), np.float64)  # [E, 9]
    a1 = np.take_along_axis(amp, nearest[..., None], -1)[..., 0]
    own = bits[nearest]  # [n, R, 9]
    others = np.einsum("nre,ec->nrc", amp, bits) - a1[..., None] * own
    a_th = float(rx.detection_amplitude(params))
    margin = 5 * float(rx.amplitude_noise_sd(params))
    low = np.where(own > 0, a1[..., None] - others, np.inf).min(-1)
    high = np.where(own > 0, a1[..., None] + others, 0.0).max(-1)
    stray = np.where(own > 0, 0.0, others).max(-1)
    clear = (
        (low >= a_th + margin)
        & (high <= float(params.max_spread) * low)
        & (stray <= np.minimum(float(params.guard) * a_th, float(params.rel_guard) * low) - margin)
    )
    return np.asarray(det.valid), np.asarray(det.mask), masks[nearest], d.min(-1), clear


@pytest.mark.parametrize("name", ["experiment", "unique11", "lattice4x2"])
def test_no_wrong_emitter_over_random_windows(params, sim, name):
    layout = {
        "experiment": ir_world.experiment_layout(),
        "unique11": ir_world.unique11_layout(),
        "lattice4x2": ir.lattice_layout(4, 2),
    }[name]
    assert layout.num_emitters == 11  # one compiled function serves all three
    seed = {"experiment": 11, "unique11": 12, "lattice4x2": 13}[name]
    valid, mask, nearest, d1, clear = _random_windows(layout, params, sim, seed=seed)
    wrong = valid & (mask != nearest)
    assert int(wrong.sum()) == 0
    # every window that is decodable whatever the phases is decoded; none beyond the range
    assert clear.sum() > 0.2 * clear.size and valid[clear].all()
    # the decoder's caution costs little: most windows within 0.26 m of an emitter are detections
    print(name, "detected within 0.26 m:", valid[d1 <= 0.26].mean(), "clear:", clear.mean())
    assert valid[d1 <= 0.26].mean() > 0.85
    assert not valid[d1 >= 0.305].any()


def test_negative_control_a_layout_breaking_the_rules_gives_wrong_emitters(params, sim):
    """Unique ``12`` 0.3 m from repeated ``1`` (rule (ii) broken): where both are in range the
    two 100 Hz waves can cancel, leaving code 2 alone — repeated ID ``2``, an emitter 0.65 m away."""
    base = ir_world.experiment_layout()
    pos = np.asarray(base.positions, np.float64).copy()
    names = ir.layout_names(base)
    pos[8] = [0.7, 0.4]
    names[8] = "12"
    bad = ir.make_layout(pos, names)  # accepted: make_layout does not enforce the decodability rules
    assert ir.code_conflicts(bad) != []
    n = 1500  # the batch size of the random-window test: no new compilation
    poses = _poses_at(0, np.tile([[0.55, 0.4]], (n, 1)), np.zeros(n), params)
    _, det = sim(_keys(5, n), poses, bad, params)
    wrong2 = np.asarray(det.valid)[:, 0] & (np.asarray(det.mask)[:, 0] == ir.to_mask(2))
    print("negative control: wrong decodes", wrong2.mean())
    # P(|2 cos(Δ/2)|·a < guard·a_th) ≈ 0.14 for a uniform phase difference Δ
    assert 0.05 < wrong2.mean() < 0.3


# ----------------------------------------------------------------------------- calibration


def test_refit_of_the_physical_sweep(params):
    e, v = rx.calibration_sweep(jax.random.PRNGKey(3), params)  # 0-300 mm, 10 mm steps, 1.2 m
    e, v = np.asarray(e, np.float64), np.asarray(v, np.float64)
    assert e.shape == v.shape == (31,)
    layout = ir.make_layout([[0.0, 0.0]], [1])
    poses = _poses_at(0, np.stack([e / 1000, np.zeros_like(e)], 1), np.zeros_like(e), params)
    clean = np.asarray(_volts(poses, layout, params), np.float64)[:, 0, 0]
    noise_rms = np.sqrt(np.mean((v - clean) ** 2))
    fit, rms = ir.fit_voltage_model(e, v)
    curve = np.asarray(ir.expected_voltage(fit, e / 1000), np.float64)
    print(
        "refit of the physical sweep:",
        [float(c) for c in fit],
        "rms",
        float(rms),
        "noise",
        noise_rms,
        "| [W] eq. 5.3:",
        list(W),
    )
    # the quadratic lies within the sweep's noise: residuals of the order of the noise
    # (the quadratic's own misfit to the physical curve is 0.02 V RMS, comparable)
    assert float(rms) == pytest.approx(np.sqrt(np.mean((curve - v) ** 2)), rel=1e-3)
    assert float(rms) < 1.5 * noise_rms
    assert np.sqrt(np.mean((curve - clean) ** 2)) < noise_rms + 0.01
    # and it is close to [W]'s curve, with its zero near the detection range
    e_in = np.arange(0.0, 281.0, 5.0)
    diff = np.asarray(ir.expected_voltage(fit, e_in / 1000)) - np.asarray(ir.expected_voltage(W, e_in / 1000))
    assert np.max(np.abs(diff)) < 0.12
    c2, c1, c0 = (float(c) for c in fit)
    zero = (-c1 - np.sqrt(c1 * c1 - 4 * c2 * c0)) / (2 * c2)
    assert abs(zero / 1000 - float(rx.detection_range(params))) < 0.012


# ----------------------------------------------------------------------------- gradients


def test_grad_of_simulated_voltage_matches_finite_differences():
    with jax.enable_x64(True):
        p64 = jax.tree.map(lambda x: jnp.asarray(x, jnp.float64), rx.default_params())
        layout = ir_world.experiment_layout()
        pose = jnp.array([0.55, 0.33, 0.4], jnp.float64)
        key = jax.random.PRNGKey(0)
        mask = ir.to_mask(1)

        def both(x):  # x = (height, led_power)
            prm = p64._replace(height=x[0], led_power=x[1])
            v_model = rx.received_voltage(pose, layout, prm)[0, 0]
            # through the sampled waveform and the FFT read-out (fixed key, noise included)
            v_meas = rx.measure_voltage(rx.sample_waveform(key, pose, layout, prm), mask, prm)[0]
            return jnp.stack([v_model, v_meas])

        # one compiled function gives the value and jax.grad-style derivatives (reverse mode)
        val_grad = jax.jit(lambda x: (both(x), jax.jacrev(both)(x)))
        x0 = jnp.array([1.2, 0.02], jnp.float64)
        v0, jac = val_grad(x0)
        jac = np.asarray(jac)  # [2 outputs, 2 inputs]
        assert 0.0 < float(v0[0])  # receiver 0 is inside emitter 0's range
        assert np.all(np.isfinite(jac))
        for i, step in enumerate((1e-6, 1e-8)):
            dx = jnp.zeros(2, jnp.float64).at[i].set(step)
            fd = (np.asarray(val_grad(x0 + dx)[0]) - np.asarray(val_grad(x0 - dx)[0])) / (2 * step)
            np.testing.assert_allclose(jac[:, i], fd, rtol=1e-5)
        assert np.all(jac[:, 0] < 0) and np.all(jac[:, 1] > 0)  # higher: fewer volts; more power: more
    # float32 gradients are finite too
    g32 = jax.grad(
        lambda h: rx.received_voltage(jnp.array([0.55, 0.33, 0.4]), layout, rx.default_params()._replace(height=h))[
            0, 0
        ]
    )(jnp.float32(1.2))
    assert np.isfinite(float(g32)) and float(g32) < 0


# ----------------------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda: rx.ReceiverConfig(fs_hz=2000.0), "twice the highest code frequency"),
        (lambda: rx.ReceiverConfig(fs_hz=2300.0), "must exceed 2300"),
        (lambda: rx.ReceiverConfig(window_s=0.015), "multiple of 0.02"),
        (lambda: rx.ReceiverConfig(window_s=0.0), "window_s"),
        (lambda: rx.ReceiverConfig(fs_hz=10_000.3), "integer number of samples"),
        (lambda: rx.default_params(height=0.0), "height"),
        (lambda: rx.default_params(height=-1.2), "height"),
        (lambda: rx.default_params(led_power=0.0), "led_power"),
        (lambda: rx.default_params(noise_sd=-0.1), "noise_sd"),
        (lambda: rx.default_params(v_offset=6.0), "below params.v_sat"),
        (lambda: rx.default_params(duty=1.0), "duty"),
        (lambda: rx.default_params(guard=0.0), "guard"),
        (lambda: rx.default_params(offsets=np.zeros((2, 3))), "offsets"),
        (lambda: rx.default_params(colour="red"), "unknown receiver parameters"),
        (lambda: rx.calibration_sweep(jax.random.PRNGKey(0), rx.default_params(), height=0.0), "height"),
        (lambda: rx.calibration_sweep(jax.random.PRNGKey(0), rx.default_params(), code=10), "codebook"),
        (lambda: rx.calibration_sweep(jax.random.PRNGKey(0), rx.default_params(), offsets_mm=[-10.0]), "offsets_mm"),
        (lambda: rx.received_voltage(jnp.zeros(2), ir_world.experiment_layout(), rx.default_params()), "pose"),
        (lambda: rx.decode(jnp.zeros((2, 199)), rx.default_params()), "waveform"),
        (
            lambda: rx.received_voltage(
                jnp.zeros(3),
                ir.EmitterLayout(
                    jnp.zeros((2, 2)), jnp.array([260, 260]), jnp.array([True, True]), jnp.array([29, 29])
                ),
                rx.default_params(),
            ),
            "duplicate unique IDs",
        ),
    ],
)
def test_bad_input_is_refused_with_a_clear_message(call, match):
    with pytest.raises(ValueError, match=match):
        call()
