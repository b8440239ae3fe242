"""IR emitter positioning models ([W] ch. 5): codebook, capacity, layouts, eq. 5.1–5.3."""

from __future__ import annotations

import itertools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnav.models import ir
from jaxnav.sim import ir_world

W = ir.W_VOLTAGE_MODEL


# ----------------------------------------------------------------------------- codebook


def test_table_5_1_codebook():
    assert ir.FREQUENCIES_HZ == (100.0, 150.0, 250.0, 350.0, 550.0, 650.0, 850.0, 950.0, 1150.0)
    assert ir.CODES == tuple(range(1, 10))
    # [W] §5.1: "ID 39 ... 0.25 kHz and 1.15 kHz"
    codes = ir.parse_name("39")
    assert codes == (3, 9)
    assert [ir.FREQUENCIES_HZ[c - 1] for c in codes] == [250.0, 1150.0]
    assert ir.id_name({9, 3}) == "39"
    assert ir.to_mask((3, 9)) == 0b100000100


def test_encode_decode_roundtrip_all_511_ids():
    seen = set()
    for i in range(ir.NUM_IDS):
        codes = ir.decode(i)
        assert ir.encode(codes) == i
        mask = ir.to_mask(codes)
        assert ir.from_mask(mask) == codes
        assert ir.parse_name(ir.id_name(codes)) == codes
        assert ir.id_name(i, is_id=True) == ir.id_name(codes)
        seen.add(codes)
    assert len(seen) == 511 == 2**9 - 1
    # every non-empty subset appears: a bijection
    assert seen == {s for k in range(1, 10) for s in itertools.combinations(range(1, 10), k)}
    # canonical numbering: repeated IDs first (id = code - 1), then pairs, ..., {1..9} last
    assert [ir.encode(c) for c in range(1, 10)] == list(range(9))
    assert ir.decode(9) == (1, 2) and ir.decode(44) == (8, 9) and ir.decode(510) == tuple(range(1, 10))
    sizes = [len(ir.decode(i)) for i in range(511)]
    assert sizes == sorted(sizes)


def test_jax_bitmask_tables_match_host_functions():
    masks = jnp.arange(512, dtype=jnp.int32)
    ids = np.asarray(jax.jit(ir.mask_to_id)(masks))
    assert ids[0] == -1
    assert [int(i) for i in ids[1:]] == [ir.encode(ir.from_mask(m)) for m in range(1, 512)]
    back = jax.jit(ir.id_to_mask)(jnp.arange(511))
    np.testing.assert_array_equal(np.asarray(back), ir.ID_TO_MASK)
    assert int(ir.id_to_mask(511)) == 0 and int(ir.mask_to_id(512)) == -1
    bits = ir.mask_bits(jnp.int32(ir.to_mask((3, 9))))
    np.testing.assert_array_equal(np.asarray(bits), [c in (3, 9) for c in range(1, 10)])
    assert int(ir.bits_to_mask(bits)) == ir.to_mask((3, 9))
    assert int(ir.popcount(jnp.int32(511))) == 9


def test_capacity_and_memory_figures_of_section_5_3():
    assert ir.capacity(9) == 511
    assert ir.capacity(9, 9) == 511
    assert ir.capacity(30, 6) == 768_211
    # "approximately 25,000 times than the raw frequencies numbers"
    assert round(ir.capacity(30, 6) / 30, -3) == 26_000
    for n in range(1, 13):
        assert ir.capacity(n) == 2**n - 1
    assert ir.capacity(9, 1) == 9 and ir.capacity(9, 2) == 9 + 36
    proposed, unique_only = ir.memory_size(600, 400)
    assert (proposed, unique_only) == (239_010, 479_001)
    assert unique_only > 2 * proposed  # "more than twice"


def test_no_harmonic_of_a_code_hits_another_code():
    assert ir.harmonic_collisions() == []
    assert ir.harmonic_collisions(max_hz=1e5) == []
    # negative control: a codebook with 100 and 300 Hz collides at the 3rd harmonic
    assert (100.0, 3, 300.0) in ir.harmonic_collisions((100.0, 300.0))


# ----------------------------------------------------------------------------- layouts


def _neighbour_pairs(pos, radius):
    d = np.sqrt(((pos[:, None] - pos[None]) ** 2).sum(-1))
    return [(i, j) for i in range(len(pos)) for j in range(i + 1, len(pos)) if d[i, j] < radius]


def _assert_decodable(layout, radius=ir.CONFLICT_RADIUS):
    """The 'Decodability' rules of jaxnav.models.ir: no union/cancellation is another layout ID."""
    masks = [int(m) for m in np.asarray(layout.masks)]
    pos = np.asarray(layout.positions, np.float64)
    unique_sizes = {bin(m).count("1") for m in masks if bin(m).count("1") >= 2}
    assert len(unique_sizes) <= 1  # rule (i)
    ids = set(masks)
    for i, j in _neighbour_pairs(pos, radius):
        union = masks[i] | masks[j]
        assert union not in ids or union in (masks[i], masks[j]), (i, j)
        shared = masks[i] & masks[j]
        for cancelled in [1 << b for b in range(9) if shared >> b & 1] + [shared]:
            if cancelled:  # shared codes cancel: what is left must not be another emitter's ID
                for m in (masks[i] & ~cancelled, masks[j] & ~cancelled, union & ~cancelled):
                    assert m == 0 or m not in ids or m in (masks[i], masks[j]), (i, j)
    rep = pos[[bin(m).count("1") == 1 for m in masks]]
    assert ir.min_separation(ir.EmitterLayout(rep, None, None, None)) >= radius  # rule (iii)
    assert ir.code_conflicts(layout, radius) == []  # rule (ii)


def test_lattice_layout_of_fig_5_1():
    lay = ir.lattice_layout()  # 5 x 5 repeated, pitch 0.80 m
    assert lay.num_emitters == 25 + 16
    pos = np.asarray(lay.positions, np.float64)
    masks = np.asarray(lay.masks)
    unique = np.asarray(lay.unique)
    assert not unique[:25].any() and unique[25:].all()
    grid = pos[:25].reshape(5, 5, 2)
    np.testing.assert_allclose(np.diff(grid[..., 0], axis=1), 0.8, atol=1e-6)
    np.testing.assert_allclose(np.diff(grid[..., 1], axis=0), 0.8, atol=1e-6)
    # unique arrays at the centre of each square of four
    centres = pos[25:].reshape(4, 4, 2)
    np.testing.assert_allclose(
        centres, 0.25 * (grid[:-1, :-1] + grid[1:, :-1] + grid[:-1, 1:] + grid[1:, 1:]), atol=1e-6
    )
    # the 8 neighbours of every repeated emitter carry a different repeated ID
    codes = masks[:25].reshape(5, 5)
    for j, i in itertools.product(range(5), range(5)):
        for dj, di in itertools.product((-1, 0, 1), repeat=2):
            if (dj or di) and 0 <= j + dj < 5 and 0 <= i + di < 5:
                assert codes[j, i] != codes[j + dj, i + di]
    assert len(set(codes.ravel())) == 9  # all nine repeated IDs used
    assert len(set(masks[25:])) == 16  # unique IDs unique
    assert ir.code_conflicts(lay) == []
    _assert_decodable(lay)
    # a wider pitch and larger lattices: bigger unique sets, still decodable
    wide = ir.lattice_layout(4, 3, pitch=1.2, origin=(1.0, -2.0))
    np.testing.assert_allclose(np.asarray(wide.positions)[1], [2.2, -2.0], atol=1e-6)
    for big in (ir.lattice_layout(6, 6), ir.lattice_layout(12, 12)):
        assert big.num_emitters > 60
        _assert_decodable(big)


def test_experiment_and_unique11_layouts_of_section_5_4():
    exp = ir_world.experiment_layout()
    names = ir.layout_names(exp)
    assert exp.num_emitters == 11
    assert int(np.sum(exp.unique)) == 3 and int(np.sum(~np.asarray(exp.unique))) == 8
    rep = [n for n, u in zip(names, np.asarray(exp.unique)) if not u]
    assert sorted(set(rep)) == ["1", "2", "4", "5"] and all(rep.count(r) == 2 for r in set(rep))
    assert "39" in names
    assert len(set(names)) == 7  # "7 IDs and microcontrollers"
    assert ir.min_separation(exp) == pytest.approx(0.8 / math.sqrt(2), rel=1e-6)
    assert ir.code_conflicts(exp) == []
    _assert_decodable(exp)
    u11 = ir_world.unique11_layout()
    assert bool(np.all(u11.unique)) and len(set(ir.layout_names(u11))) == 11
    np.testing.assert_array_equal(np.asarray(u11.positions), np.asarray(exp.positions))
    assert ir.code_conflicts(u11) == []
    _assert_decodable(u11)


def test_without_emitters_for_failure_experiments():
    exp = ir_world.experiment_layout()
    # [W] §5.4.5: two emitters of the same ID lose power
    same = [i for i, n in enumerate(ir.layout_names(exp)) if n == "4"]
    assert len(same) == 2
    failed = ir.without_emitters(exp, same)
    assert failed.num_emitters == 9
    assert "4" not in ir.layout_names(failed)
    keep = [i for i in range(11) if i not in same]
    np.testing.assert_array_equal(np.asarray(failed.positions), np.asarray(exp.positions)[keep])
    ir.validate_layout(failed)


# ----------------------------------------------------------------------------- voltage model


def test_eq_5_3_and_likelihood_eq_5_2():
    e = jnp.array([0.0, 0.1, 0.2836])
    v = ir.expected_voltage(W, e)
    assert float(v[0]) == pytest.approx(1.81997, abs=1e-6)
    assert float(v[1]) == pytest.approx(-3.27e-5 * 1e4 + 2.855e-3 * 100 + 1.81997, abs=1e-5)
    assert abs(float(v[2])) < 2e-3  # zero crossing ~283.6 mm: the detection range
    ll = ir.log_likelihood(v, e, W, 0.1, log_alpha=-1.5)
    np.testing.assert_allclose(np.asarray(ll), -1.5, atol=1e-6)
    ll2 = ir.log_likelihood(v + 0.2, e, W, 0.1)
    np.testing.assert_allclose(np.asarray(ll2), -0.5 * 4.0, rtol=1e-4)


def _sweep_design(e_mm):
    return np.stack([e_mm**2, e_mm, np.ones_like(e_mm)], axis=1)


def test_refit_recovers_w_coefficients():
    e = np.arange(0.0, 301.0, 10.0)  # [W]: 0-300 mm at 10 mm steps
    v_true = np.asarray(ir.expected_voltage(W, e / 1000.0), np.float64)
    # noise-free: the optimum is the truth
    fit, rms = ir.fit_voltage_model(e, v_true)
    np.testing.assert_allclose(np.array(fit, np.float64), np.array(W), rtol=2e-4)
    assert float(rms) < 1e-4
    # with noise sd 0.02 V: within 4 standard errors of OLS theory, and at the OLS optimum
    sd = 0.02
    v = v_true + sd * np.random.default_rng(0).standard_normal(e.shape)
    fit, rms = ir.fit_voltage_model(e, v)
    x = _sweep_design(e)
    se = np.sqrt(np.diag(sd**2 * np.linalg.inv(x.T @ x)))
    err = np.array(fit, np.float64) - np.array(W)
    assert np.all(np.abs(err) < 4 * se), (err, se)
    ols = np.linalg.lstsq(x, v, rcond=None)[0]
    assert np.all(np.abs(np.array(fit, np.float64) - ols) < 0.01 * se)  # optax reached the optimum
    # the residual RMS estimates the noise: E[rms²] = sd²·(n-3)/n
    assert 0.6 * sd < float(rms) < 1.4 * sd
    # a warm start gives the same answer
    fit2, _ = ir.fit_voltage_model(e, v, init=W)
    assert np.all(np.abs(np.array(fit2, np.float64) - ols) < 0.01 * se)


# ----------------------------------------------------------------------------- belief


def test_belief_picks_nearest_emitter_of_the_repeated_id():
    lay = ir.make_layout([[0.0, 0.0], [2.0, 0.0], [0.0, 2.0], [1.0, 1.0], [3.0, 3.0]], [1, 1, 1, "23", 2])
    m1 = ir.to_mask(1)
    idx, ok = ir.select_emitter(jnp.array([1.8, 0.1]), m1, lay)
    assert bool(ok) and int(idx) == 1
    idx, ok = ir.select_emitter(jnp.array([0.2, 1.5]), m1, lay)
    assert bool(ok) and int(idx) == 2
    # the belief of eq. 5.1 is maximal at the chosen emitter
    lb = ir.log_belief(lay.positions, jnp.array([0.2, 1.5]))
    assert int(jnp.argmax(jnp.where(lay.masks == m1, lb, -jnp.inf))) == 2
    # a unique ID: its only emitter, wherever the estimate is
    idx, ok = ir.select_emitter(jnp.array([3.0, 3.0]), ir.to_mask((2, 3)), lay)
    assert bool(ok) and int(idx) == 3
    # an ID the layout does not hold, and no detection: invalid, index -1
    for m in (ir.to_mask(7), 0):
        idx, ok = ir.select_emitter(jnp.array([0.0, 0.0]), m, lay)
        assert not bool(ok) and int(idx) == -1


def test_belief_matches_brute_force_on_lattice():
    lay = ir.lattice_layout()
    n = 400
    rng = np.random.default_rng(1)
    pos = jnp.asarray(rng.uniform(-0.5, 3.7, (n, 2)), jnp.float32)
    masks = jnp.asarray(ir.ID_TO_MASK[rng.integers(0, 9, n)])  # repeated IDs 1-9
    idx, ok = jax.jit(jax.vmap(ir.select_emitter, in_axes=(0, 0, None)))(pos, masks, lay)
    assert bool(jnp.all(ok))
    P = np.asarray(lay.positions, np.float64)
    M = np.asarray(lay.masks)
    for p, m, i in zip(np.asarray(pos, np.float64), np.asarray(masks), np.asarray(idx)):
        cand = np.flatnonzero(M == m)
        d = np.linalg.norm(P[cand] - p, axis=1)
        assert np.linalg.norm(P[i] - p) <= d.min() + 1e-6
        assert M[i] == m


# ----------------------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda: ir.encode((0,)), "not in the codebook"),
        (lambda: ir.encode((3, 10)), "not in the codebook"),
        (lambda: ir.encode(()), "non-empty"),
        (lambda: ir.encode((3, 3)), "repeats a code"),
        (lambda: ir.parse_name("30"), "not in the codebook"),
        (lambda: ir.parse_name("x9"), "code digits"),
        (lambda: ir.decode(511), "0–510"),
        (lambda: ir.from_mask(0), "1–511"),
        (lambda: ir.capacity(0), "n_frequencies"),
        (lambda: ir.make_layout([[0, 0], [1, 1]], ["39", (9, 3)]), "duplicate unique IDs"),
        (lambda: ir.make_layout([[0, 0]], [(1, 12)]), "not in the codebook"),
        (lambda: ir.make_layout([[0, 0], [1, 1]], [1]), "entries"),
        (lambda: ir.lattice_layout(pitch=0.0), "pitch"),
        (lambda: ir.lattice_layout(pitch=-0.8), "pitch"),
        (lambda: ir.lattice_layout(pitch=0.65), "conflict_radius"),
        (lambda: ir.lattice_layout(14, 14), "use a smaller lattice"),
        (lambda: ir.lattice_layout(1, 5), "at least 2"),
        (lambda: ir.lattice_layout(repeated_codes=(1, 2, 3)), "at least 4"),
        (lambda: ir_world.experiment_layout(pitch=0.0), "pitch"),
        (lambda: ir.without_emitters(ir_world.experiment_layout(), [11]), "out of range"),
        (lambda: ir.without_emitters(ir_world.experiment_layout(), range(11)), "every emitter"),
        (lambda: ir.fit_voltage_model([0.0, 10.0], [1.0, 0.9]), "at least 3"),
        (lambda: ir.fit_voltage_model([0.0, 10.0, 20.0], [1.0, np.nan, 0.9]), "NaN"),
        (lambda: ir.fit_voltage_model([0.0, 10.0, 20.0], [1.0, 0.9]), "shape"),
    ],
)
def test_bad_input_is_refused_with_a_clear_message(call, match):
    with pytest.raises(ValueError, match=match):
        call()
