"""HF-RFID world simulator: tag carpets, reader arrays and drives over them ([W] ch. 3–4).

The commanded trajectories (rectangle, random) are :mod:`jaxnav.sim.trajectories`.

**Overview**

A floor carpet holds passive HF tags on a square lattice of pitch ``p``
([W] §3.1, Fig. 3.2): 100 tags/m² (p = 0.10 m), 16 tags/m² (0.25 m) or
4 tags/m² (0.50 m, [W] §4.4). Tag ``(ix, iy)`` sits at::

    m = origin + p·(ix, iy) + j,     |j_x|, |j_y| ≤ J < p/2

with ``j`` an installation error drawn uniform in ``[-J, J]`` per axis ("they
are installed with unavoidable errors", [W] §3.1). Its unique ID is
``n = iy·nx + ix`` (the filters' tag-table slot). The static part of a carpet
(:class:`CarpetLayout`: pitch, size, origin, J) is hashable and is a pytree
with no leaves, so a :class:`TagCarpet` ``(layout, jitter)`` can be passed to
``jax.jit`` and retraces only when the layout changes.

**Detection by lattice arithmetic**

``B`` readers under the robot (:mod:`jaxnav.models.hf_rfid`) each see a square
of half-width σ around their centre, turning with the robot. Reader ``b``
detects tag ``n`` iff ``|e_x| < σ`` and ``|e_y| < σ`` (strict, [W] eq. 3.7's
"inside" case) with ``e = R(θ)ᵀ(m_n − p) − o_b``. A step never looks at
every tag ([W] §3.3.1): the footprint's world bounding box has half-extent
``σ(|cos θ| + |sin θ|) ≤ σ√2``; widened by ``J`` (a tag is at most ``J`` from
its lattice point) and a rounding slack of ``10⁻³p`` it contains the lattice
points of every tag the reader can see. Its lattice indices are
``floor((c − R − origin)/p) + a`` for ``a = 0 … n−1`` per axis, with the
*static* count ``n = floor(2(σ̄√2 + J + slack)/p) + 2`` (σ̄ the static
footprint bound, see below). Each candidate is then tested exactly; indices
off the carpet are masked. The cost is ``B·n²`` candidates whatever the
carpet size: a 10-tag and a 10⁵-tag carpet give the same computation except
for the size of the jitter table it gathers from.

Shapes cannot depend on traced values, and :class:`~jaxnav.models.hf_rfid.HFReaderParams`
holds σ as an array (it is differentiable). The candidate count therefore
comes from a static ``footprint_side`` (m): by default the concrete
``2·readers.half_width`` read on the host; inside a user's ``jit`` pass it
explicitly (the traced σ must not exceed ``footprint_side/2``).

Detections of one step fill ``K = max_detections`` slots
(:class:`~jaxnav.models.hf_rfid.TagDetections`): valid slots first, in
reader-major order and, per reader, increasing tag ID; the same tag seen by
two readers fills two slots. Unused slots hold ``ids = readers = −1`` and
``mask = False`` (consumers must use the mask; a scatter with ``−1`` would
wrap to the last row). :func:`detection_capacity` is a rigorous upper bound
on detections per step (see its docstring); it is the default ``K`` and a
smaller ``K`` is refused, so no detection is ever dropped.

**Simulation protocol**

Controls are rows ``(v_x, v_y, ω, Δt)`` in the world frame, the ``omni``
model of [W] eq. 3.6 (:mod:`jaxnav.models.motion`). At step ``t`` the true
robot moves exactly with ``controls[t]`` (so a rectangle is driven exactly and
is comparable with the estimate, as in [W] §3.4.1), then detects at its new
pose. The filter receives odometry ``controls[t] + (ε, Δt)`` with
``ε ~ N(0, diag(σ_odo²))`` in (m/s, m/s, rad/s): [W] eq. 3.6's ``ε·Δt`` is the
pose error it causes. With ``motion_model="omni_body"`` the velocities are
first rotated into the robot frame with the true heading before the move
(the frame :func:`jaxnav.models.motion.omni_body_mean` uses), then noised.
Kidnapping ([W] §3.4.3): at the step of a :class:`Kidnap` the robot is
teleported (no motion) and the odometry row reports zero velocity (Δt kept),
so the filter gets no motion information.

**Smooth relaxation**

For gradient work the footprint indicator is replaced by
``Π_axes s((σ − e)/τ)·s((σ + e)/τ)`` (``s`` the logistic function), which
tends to the indicator as τ → 0 (:func:`jaxnav.models.hf_rfid.soft_inside`), and a run's detections
and non-detections are scored as Bernoulli outcomes
(:func:`jaxnav.models.hf_rfid.soft_detection_log_likelihood`, which reads the carpet
through :func:`tag_map`), differentiable in σ, τ and the poses.

Units are SI (m, rad, s); arrays are float32 unless x64 is enabled.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.core import rng
from jaxnav.core.filter import check_key
from jaxnav.core.validation import (
    MAX_MAGNITUDE,
    check_finite,
    check_magnitude,
    check_nonnegative,
    check_shape,
    is_concrete,
)
from jaxnav.models import hf_rfid
from jaxnav.models.motion import OmniNoise, omni_mean
from jaxnav.sim.trajectories import rectangle_controls

__all__ = [
    "CarpetLayout",
    "TagCarpet",
    "Kidnap",
    "HFRun",
    "DENSITY_PITCH",
    "density_to_pitch",
    "make_carpet",
    "tag_positions",
    "tag_ids",
    "tag_indices",
    "candidates_per_axis",
    "detection_capacity",
    "detect",
    "detect_brute_force",
    "simulate",
    "kidnapping_scenario",
    "tag_map",
]

DENSITY_PITCH = {100: 0.10, 16: 0.25, 4: 0.50}
"""The carpets of [W], tags/m² → lattice pitch (m)."""

_SLACK = 1e-3
"""Rounding slack of the candidate window, as a fraction of the pitch."""

_SQRT2 = math.sqrt(2.0)


def _float_dtype():
    """float32, or float64 when x64 is enabled."""
    return jnp.zeros(()).dtype


# ---------------------------------------------------------------------------
# carpet


@dataclasses.dataclass(frozen=True)
class CarpetLayout:
    """Static description of a tag carpet (hashable; a pytree with no leaves).

    Attributes:
        pitch: lattice pitch p (m).
        nx: tags along x.
        ny: tags along y.
        origin: ``(x0, y0)`` world position (m) of nominal tag ``(0, 0)``.
        max_jitter: J, bound on the installation error per axis (m), ``0 ≤ J < p/2``.
    """

    pitch: float
    nx: int
    ny: int
    origin: tuple[float, float] = (0.0, 0.0)
    max_jitter: float = 0.0

    def __post_init__(self):
        pitch = float(self.pitch)
        if not (math.isfinite(pitch) and pitch > 0):
            raise ValueError(f"pitch must be a finite number > 0 m, got {self.pitch!r}")
        for name in ("nx", "ny"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise ValueError(f"{name} (tags per axis) must be a positive integer, got {v!r}")
        origin = tuple(float(o) for o in self.origin)
        if len(origin) != 2 or not all(math.isfinite(o) for o in origin):
            raise ValueError(f"origin must be two finite numbers (x0, y0) in m, got {self.origin!r}")
        jit = float(self.max_jitter)
        if not (math.isfinite(jit) and 0 <= jit < pitch / 2):
            raise ValueError(
                f"max_jitter must be in [0, pitch/2) = [0, {pitch / 2:g}) m, got {self.max_jitter!r}; "
                "a larger installation error would let two tags swap lattice cells"
            )
        object.__setattr__(self, "pitch", pitch)
        object.__setattr__(self, "nx", int(self.nx))
        object.__setattr__(self, "ny", int(self.ny))
        object.__setattr__(self, "origin", origin)
        object.__setattr__(self, "max_jitter", jit)

    @property
    def num_tags(self) -> int:
        """``nx·ny``."""
        return self.nx * self.ny

    @property
    def density(self) -> float:
        """Tags per m², ``1/p²``."""
        return 1.0 / (self.pitch * self.pitch)

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """``(xmin, ymin, xmax, ymax)`` of the nominal lattice (m)."""
        x0, y0 = self.origin
        return (x0, y0, x0 + (self.nx - 1) * self.pitch, y0 + (self.ny - 1) * self.pitch)


jax.tree_util.register_static(CarpetLayout)


class TagCarpet(NamedTuple):
    """A tag carpet: static layout and the installation errors of its tags.

    Attributes:
        layout: :class:`CarpetLayout` (static: no leaves, part of the tree structure).
        jitter: ``[num_tags, 2]`` installation error of each tag (m), row = tag ID.
    """

    layout: CarpetLayout
    jitter: jax.Array


def density_to_pitch(density: float) -> float:
    """Lattice pitch ``1/√density`` (m) of a carpet of ``density`` tags/m² (100 → 0.10 m)."""
    d = float(density)
    if not (math.isfinite(d) and d > 0):
        raise ValueError(f"density must be a finite number > 0 tags/m², got {density!r} ([W] uses 100, 16 and 4)")
    return 1.0 / math.sqrt(d)


def make_carpet(
    key: jax.Array,
    area: tuple[float, float] = (2.0, 2.0),
    density: float | None = None,
    pitch: float | None = None,
    origin: tuple[float, float] = (0.0, 0.0),
    jitter: float = 0.01,
) -> TagCarpet:
    """A carpet covering ``area = (w, h)`` m from ``origin`` with uniform installation errors.

    Args:
        key: PRNG key for the installation errors.
        area: ``(w, h)`` in m; ``nx = floor(w/p) + 1`` and ``ny = floor(h/p) + 1``
            tags (a tag on both borders when ``w`` is a multiple of ``p``).
        density: tags/m² (100, 16, 4 in [W]); gives ``p = 1/√density``.
        pitch: lattice pitch ``p`` (m). Give exactly one of ``density`` and ``pitch``.
        origin: world position (m) of nominal tag ``(0, 0)``.
        jitter: J (m); each tag is displaced by ``U[−J, J]`` per axis. Must be ``< p/2``.
    """
    check_key(key)
    if (density is None) == (pitch is None):
        raise ValueError("give exactly one of density (tags/m²: 100, 16 or 4 in [W]) and pitch (m)")
    p = density_to_pitch(density) if density is not None else float(pitch)
    if not (math.isfinite(p) and p > 0):
        raise ValueError(f"pitch must be a finite number > 0 m, got {pitch!r}")
    try:
        w, h = (float(a) for a in area)
    except (TypeError, ValueError):
        raise ValueError(f"area must be (width, height) in m, got {area!r}") from None
    if not (math.isfinite(w) and math.isfinite(h) and 0 <= w <= MAX_MAGNITUDE and 0 <= h <= MAX_MAGNITUDE):
        raise ValueError(f"area must be two finite numbers in [0, {MAX_MAGNITUDE:g}] m, got {area!r}")
    j = float(jitter)
    if not (math.isfinite(j) and 0 <= j < p / 2):
        raise ValueError(f"jitter must be in [0, pitch/2) = [0, {p / 2:g}) m for pitch {p:g} m, got {jitter!r}")
    nx = int(math.floor(w / p + 1e-9)) + 1
    ny = int(math.floor(h / p + 1e-9)) + 1
    layout = CarpetLayout(p, nx, ny, tuple(origin), j)
    # Drawn in a power-of-two block (then cut), so that carpets of similar size
    # share one compiled sampler instead of compiling one per tag count.
    block = max(64, 1 << (layout.num_tags - 1).bit_length())
    errors = rng.uniform(key, (block, 2), _float_dtype(), -j, j)[: layout.num_tags]
    return TagCarpet(layout, errors)


def tag_ids(layout: CarpetLayout, ix: jax.Array, iy: jax.Array) -> jax.Array:
    """Tag ID ``iy·nx + ix`` (int32) of lattice indices ``(ix, iy)``."""
    return (jnp.asarray(iy, jnp.int32) * layout.nx + jnp.asarray(ix, jnp.int32)).astype(jnp.int32)


def tag_indices(layout: CarpetLayout, ids: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Lattice indices ``(ix, iy)`` of tag IDs (inverse of :func:`tag_ids`)."""
    ids = jnp.asarray(ids, jnp.int32)
    return ids % layout.nx, ids // layout.nx


def _nominal(layout: CarpetLayout, ix: jax.Array, iy: jax.Array, dtype) -> jax.Array:
    x0, y0 = layout.origin
    return jnp.stack([x0 + ix.astype(dtype) * layout.pitch, y0 + iy.astype(dtype) * layout.pitch], axis=-1)


def tag_positions(carpet: TagCarpet) -> jax.Array:
    """``[num_tags, 2]`` world positions (m) of all tags, row = tag ID (for plots, tests and errors)."""
    layout = carpet.layout
    ix, iy = tag_indices(layout, jnp.arange(layout.num_tags, dtype=jnp.int32))
    return _nominal(layout, ix, iy, carpet.jitter.dtype) + carpet.jitter


def _check_carpet(carpet: TagCarpet, name: str = "carpet", values: bool = False) -> None:
    """Type and shape of a carpet; with ``values`` also its jitter (O(N): once per run, not per detect)."""
    if not isinstance(carpet, TagCarpet) or not isinstance(carpet.layout, CarpetLayout):
        raise ValueError(f"{name} must be a TagCarpet(layout, jitter); build one with tag_carpet.make_carpet")
    check_shape(f"{name}.jitter", carpet.jitter, (carpet.layout.num_tags, 2))
    if values and is_concrete(carpet.jitter):
        v = np.asarray(carpet.jitter)
        if not np.all(np.isfinite(v)) or np.max(np.abs(v), initial=0.0) > carpet.layout.max_jitter * (1 + 1e-6) + 1e-12:
            raise ValueError(
                f"{name}.jitter must be finite with |jitter| ≤ layout.max_jitter = {carpet.layout.max_jitter} m"
            )


# ---------------------------------------------------------------------------
# static bounds


def candidates_per_axis(layout: CarpetLayout, side: float) -> int:
    """Static number ``n`` of lattice indices per axis searched around one reader.

    ``n = floor(2(σ√2 + J + slack)/p) + 2`` with ``σ = side/2``: enough for a
    footprint of ``side`` metres at any heading (module docstring); the lattice
    search of one reader visits ``n²`` candidates.
    """
    s = float(side)
    if not (math.isfinite(s) and s > 0):
        raise ValueError(f"footprint side must be a finite number > 0 m, got {side!r}")
    reach = 0.5 * s * _SQRT2 + layout.max_jitter + _SLACK * layout.pitch
    return int(math.floor(2.0 * reach / layout.pitch)) + 2


def detection_capacity(layout: CarpetLayout, side: float, offsets: Any) -> int:
    """Upper bound on detections in one step by the ``B`` readers of ``offsets [B, 2]``.

    Per reader, the tags inside an open square of side ``s`` at any heading are
    bounded two ways, and the smaller bound is used:

    * lattice count: their nominal x coordinates lie in an interval of length
      ``2(s/√2 + J)``, which holds at most ``floor(2(s/√2 + J)/p) + 1`` lattice
      values; the same for y; the product bounds the tags;
    * packing: two tags differ by at least ``d = p − 2J`` along some lattice
      axis, so the axis-aligned squares of side ``d`` around them are disjoint
      and lie in the footprint grown by ``d/2``, of area at most
      ``s² + d² + 2√2·s·d``; hence at most that area ``/ d²`` tags;
    * lattice points in a convex set: the nominal points lie in the footprint
      grown by the jitter square ``[−J, J]²``, a convex set of area
      ``A ≤ s² + 4J² + 4√2·s·J`` and perimeter ``P = 4s + 8J``, which holds at
      most ``A/p² + P/(2p) + 1`` lattice points (Bokowski, Hadwiger and Wills'
      inequality, 1972).

    * the carpet: a reader cannot detect more tags than the carpet holds.

    A micrometre of slack covers floating-point rounding. The total is ``B``
    times the per-reader bound (a tag seen by two readers fills two slots). It
    does not depend on the carpet size unless a footprint covers most of the
    carpet. Examples (J = 10 mm, 8 readers):
    60 mm readers on 0.10 m pitch → 3 per reader, 24 in all; 300 mm readers on
    0.50 m pitch → 1 per reader, 8 in all; 300 mm readers on 0.10 m pitch → 18
    per reader, 144 in all.
    """
    s = float(side)
    if not (math.isfinite(s) and s > 0):
        raise ValueError(f"footprint side must be a finite number > 0 m, got {side!r}")
    b = int(np.shape(offsets)[0]) if np.ndim(offsets) >= 1 else int(offsets)
    if b < 1:
        raise ValueError(f"offsets must hold at least one reader, got shape {np.shape(offsets)}")
    p, j = layout.pitch, layout.max_jitter
    s_eff = s + 2e-6
    per_axis = int(math.floor(2.0 * (0.5 * s_eff * _SQRT2 + j) / p)) + 1
    d = p - 2.0 * j - 2e-6
    packing = int(math.floor((s_eff * s_eff + d * d + 2.0 * _SQRT2 * s_eff * d) / (d * d)))
    j_eff = j + 1e-6
    area = s_eff * s_eff + 4.0 * j_eff * j_eff + 4.0 * _SQRT2 * s_eff * j_eff
    convex = int(math.floor(area / (p * p) + (4.0 * s_eff + 8.0 * j_eff) / (2.0 * p) + 1.0))
    return b * max(1, min(per_axis * per_axis, packing, convex, layout.num_tags))


def _static_side(readers: hf_rfid.HFReaderParams, footprint_side: float | None, what: str) -> float:
    """The static footprint side: ``footprint_side`` or the concrete ``2·readers.half_width``."""
    if footprint_side is None:
        if not is_concrete(readers.half_width):
            raise ValueError(
                f"{what}: readers.half_width is traced, so the static candidate window is unknown; "
                "pass footprint_side=<reader footprint side in m> (a Python float)"
            )
        side = 2.0 * float(np.asarray(readers.half_width))
    else:
        side = float(footprint_side)
    if not (math.isfinite(side) and side > 0):
        raise ValueError(f"{what}: the reader footprint side must be > 0 m, got {side!r}; [W] uses 0.06 to 0.5")
    if footprint_side is not None and is_concrete(readers.half_width):
        hw = float(np.asarray(readers.half_width))
        if 2.0 * hw > side * (1 + 1e-6):
            raise ValueError(
                f"{what}: footprint_side={side} m is smaller than the readers' footprint 2·half_width={2 * hw} m; "
                "pass footprint_side ≥ the footprint"
            )
    return side


def _resolve_capacity(layout: CarpetLayout, side: float, offsets, max_detections: int | None, what: str) -> int:
    cap = detection_capacity(layout, side, offsets)
    if max_detections is None:
        return cap
    if isinstance(max_detections, bool) or not isinstance(max_detections, (int, np.integer)) or max_detections < 1:
        raise ValueError(f"{what}: max_detections must be a positive integer, got {max_detections!r}")
    if int(max_detections) < cap:
        raise ValueError(
            f"{what}: max_detections={max_detections} is below the detection capacity {cap} "
            f"({np.shape(offsets)[0]} readers, {side * 1000:g} mm footprint, pitch {layout.pitch * 1000:g} mm, "
            f"jitter {layout.max_jitter * 1000:g} mm), so detections could be dropped; "
            f"pass max_detections ≥ {cap} or None (the default uses the capacity)"
        )
    return int(max_detections)


# ---------------------------------------------------------------------------
# detection


def _candidates(layout: CarpetLayout, jitter: jax.Array, pose: jax.Array, offsets: jax.Array, window: float, n: int):
    """Lattice candidates around each reader: ``ids [B, n²]``, ``pos [B, n², 2]``, ``on_carpet [B, n²]``.

    The candidates cover every tag whose position can lie in a square of
    half-width ``window`` around the reader, at the pose's heading.
    """
    dtype = jnp.result_type(pose.dtype, jitter.dtype)
    pose = pose.astype(dtype)
    centres = hf_rfid.world_frame(pose, offsets.astype(dtype))  # [B, 2]
    s, c = jnp.sin(pose[2]), jnp.cos(pose[2])
    reach = window * (jnp.abs(c) + jnp.abs(s)) + layout.max_jitter + _SLACK * layout.pitch
    origin = jnp.asarray(layout.origin, dtype)
    start = jnp.floor((centres - reach - origin) / layout.pitch).astype(jnp.int32)  # [B, 2]
    a = jnp.arange(n, dtype=jnp.int32)
    ax, ay = jnp.meshgrid(a, a, indexing="xy")  # row-major over (ay, ax): increasing ID
    ix = start[:, 0:1] + ax.reshape(1, -1)
    iy = start[:, 1:2] + ay.reshape(1, -1)
    on = (ix >= 0) & (ix < layout.nx) & (iy >= 0) & (iy < layout.ny)
    ids = jnp.where(on, iy * layout.nx + ix, 0).astype(jnp.int32)
    pos = _nominal(layout, ix, iy, dtype) + jnp.take(jitter, ids, axis=0).astype(dtype)
    return ids, pos, on


def _compact(valid: jax.Array, ids: jax.Array, readers: jax.Array, k: int) -> hf_rfid.TagDetections:
    """Stable compaction of flat candidates into ``k`` slots, valid first."""
    valid = valid.reshape(-1)
    slot = jnp.cumsum(valid.astype(jnp.int32)) - 1
    target = jnp.where(valid, slot, k)  # invalid → out of range → dropped
    out_ids = jnp.full((k,), -1, jnp.int32).at[target].set(ids.reshape(-1), mode="drop")
    out_readers = jnp.full((k,), -1, jnp.int32).at[target].set(readers.reshape(-1), mode="drop")
    mask = jnp.arange(k) < jnp.sum(valid)
    return hf_rfid.TagDetections(out_ids, out_readers, mask)


def _detect(carpet: TagCarpet, pose: jax.Array, offsets: jax.Array, half_width: jax.Array, side: float, n: int, k: int):
    ids, pos, on = _candidates(carpet.layout, carpet.jitter, pose, offsets, 0.5 * side, n)
    e = hf_rfid.robot_frame(pose.astype(pos.dtype), pos) - offsets.astype(pos.dtype)[:, None, :]
    inside = jnp.all(jnp.abs(e) < half_width.astype(pos.dtype), axis=-1)
    readers = jnp.broadcast_to(jnp.arange(offsets.shape[0], dtype=jnp.int32)[:, None], ids.shape)
    return _compact(on & inside, ids, readers, k)


_detect_jit = jax.jit(_detect, static_argnames=("side", "n", "k"))


def detect(
    carpet: TagCarpet,
    pose: jax.Array,
    readers: hf_rfid.HFReaderParams,
    max_detections: int | None = None,
    footprint_side: float | None = None,
) -> hf_rfid.TagDetections:
    """Tags detected by each reader at ``pose`` (lattice lookup; cost independent of the carpet size).

    Reader ``b`` detects tag ``n`` iff ``|e_x| < σ`` and ``|e_y| < σ`` with
    ``e = robot_frame(pose, m_n) − offsets[b]`` and ``σ = readers.half_width``
    ([W] eq. 3.7, "inside"; [W] §3.1).

    Args:
        carpet: the :class:`TagCarpet`.
        pose: ``[3]`` robot pose ``(x, y, θ)`` (m, m, rad).
        readers: reader array (``offsets [B, 2]``, ``half_width``) from
            :func:`jaxnav.models.hf_rfid.reader_params`.
        max_detections: ``K`` slots; default and minimum :func:`detection_capacity`.
        footprint_side: static footprint side (m) fixing the candidate window;
            default the concrete ``2·readers.half_width``. Needed when ``readers``
            is traced; the traced σ must not exceed ``footprint_side/2``.

    Returns:
        :class:`~jaxnav.models.hf_rfid.TagDetections` with ``K`` slots, valid
        first, reader-major, increasing ID per reader; unused slots ``−1``.
    """
    _check_carpet(carpet)
    hf_rfid.validate_params(readers, "readers")
    check_shape("pose", pose, (3,))
    check_finite("pose", pose)
    side = _static_side(readers, footprint_side, "detect")
    k = _resolve_capacity(carpet.layout, side, readers.offsets, max_detections, "detect")
    n = candidates_per_axis(carpet.layout, side)
    return _detect_jit(carpet, jnp.asarray(pose), readers.offsets, readers.half_width, side, n, k)


def detect_brute_force(positions: Any, pose: Any, readers: hf_rfid.HFReaderParams) -> tuple[np.ndarray, np.ndarray]:
    """NumPy float64 reference: test every tag against every reader.

    Args:
        positions: ``[N, 2]`` tag positions (m), row = tag ID.
        pose: ``[3]`` robot pose.
        readers: reader array.

    Returns:
        ``(tag_ids, reader_ids)`` int arrays of the detected pairs, reader-major
        and by increasing tag ID per reader (the slot order of :func:`detect`).
    """
    pos = np.asarray(positions, np.float64)
    x, y, th = (float(v) for v in np.asarray(pose, np.float64))
    off = np.asarray(readers.offsets, np.float64)
    hw = float(np.asarray(readers.half_width, np.float64))
    c, s = math.cos(th), math.sin(th)
    dx, dy = pos[:, 0] - x, pos[:, 1] - y
    rx, ry = c * dx + s * dy, -s * dx + c * dy
    ex = rx[None, :] - off[:, 0:1]
    ey = ry[None, :] - off[:, 1:2]
    inside = (np.abs(ex) < hw) & (np.abs(ey) < hw)
    reader_ids, tag_ids_ = np.nonzero(inside)
    return tag_ids_.astype(np.int64), reader_ids.astype(np.int64)


# ---------------------------------------------------------------------------
# simulation


class Kidnap(NamedTuple):
    """A kidnapping ([W] §3.4.3): at step ``step`` the robot is put at ``pose`` without motion.

    Attributes:
        step: int index of the step at which the robot is teleported.
        pose: ``[3]`` pose it is put at (m, m, rad).
    """

    step: jax.Array
    pose: jax.Array


class HFRun(NamedTuple):
    """A simulated HF-RFID run of ``T`` steps.

    Attributes:
        true_poses: ``[T, 3]`` true pose after step ``t`` (m, m, rad).
        odometry: ``[T, 4]`` what the filter receives: ``(v_x, v_y, ω, Δt)``
            with velocity noise, world frame (``omni``) or robot frame (``omni_body``).
        detections: :class:`~jaxnav.models.hf_rfid.TagDetections`, leading axis ``T``.
        kidnapped: ``[T]`` bool, True at the step of a kidnapping.
        start_pose: ``[3]`` the known start pose ([W]: "the robot starts with a known position").
    """

    true_poses: jax.Array
    odometry: jax.Array
    detections: hf_rfid.TagDetections
    kidnapped: jax.Array
    start_pose: jax.Array


def _simulate(key, carpet, offsets, half_width, start_pose, controls, sd, kid_step, kid_pose, motion_model, side, n, k):
    dtype = controls.dtype
    noise = rng.normal(key, (controls.shape[0], 3), dtype) * sd.astype(dtype)

    def body(pose, inputs):
        t, u, eps = inputs
        is_k = t == kid_step
        moved = omni_mean(pose, u)
        new = jnp.where(is_k, kid_pose.astype(dtype), moved)
        if motion_model == "omni_body":
            s, c = jnp.sin(pose[2]), jnp.cos(pose[2])
            v = jnp.stack([c * u[0] + s * u[1], -s * u[0] + c * u[1], u[2]])
        else:
            v = u[:3]
        odo = jnp.concatenate([jnp.where(is_k, jnp.zeros_like(v), v + eps), u[3:4]])
        det = _detect(carpet, new, offsets, half_width, side, n, k)
        return new, (new, odo, det, is_k)

    t = jnp.arange(controls.shape[0], dtype=jnp.int32)
    _, (poses, odo, det, kid) = jax.lax.scan(body, start_pose.astype(dtype), (t, controls, noise))
    return HFRun(poses, odo, det, kid, start_pose.astype(dtype))


_simulate_jit = jax.jit(_simulate, static_argnames=("motion_model", "side", "n", "k"))


def simulate(
    key: jax.Array,
    carpet: TagCarpet,
    readers: hf_rfid.HFReaderParams,
    start_pose: jax.Array,
    controls: jax.Array,
    odometry_sd: Any,
    max_detections: int | None = None,
    motion_model: str = "omni",
    kidnap: Kidnap | None = None,
    footprint_side: float | None = None,
) -> HFRun:
    """Drive ``controls`` over ``carpet`` and record odometry and detections (one ``lax.scan``).

    Protocol (module docstring): the true robot moves exactly with
    ``controls[t]`` (world-frame ``(v_x, v_y, ω, Δt)``, [W] eq. 3.6 without
    noise), then detects with :func:`detect`; the odometry row is
    ``controls[t]`` with ``N(0, odometry_sd²)`` added to the velocities (rotated
    into the robot frame first for ``motion_model="omni_body"``). At a
    :class:`Kidnap` step the robot is put at ``kidnap.pose`` and the odometry
    row is ``(0, 0, 0, Δt)``.

    Args:
        key: PRNG key (odometry noise).
        carpet: :class:`TagCarpet`.
        readers: reader array (:func:`jaxnav.models.hf_rfid.reader_params`).
        start_pose: ``[3]`` pose before the first step.
        controls: ``[T, 4]`` world-frame controls (:func:`jaxnav.sim.trajectories.rectangle_controls`, :func:`jaxnav.sim.trajectories.random_controls`).
        odometry_sd: ``[3]`` σ of [W] eq. 3.6 (m/s, m/s, rad/s), or an
            :class:`~jaxnav.models.motion.OmniNoise`.
        max_detections: ``K``; default and minimum :func:`detection_capacity`.
        motion_model: ``"omni"`` or ``"omni_body"``, the frame of the odometry.
        kidnap: optional :class:`Kidnap`.
        footprint_side: static footprint side (m), see :func:`detect`.
    """
    _check_carpet(carpet, values=True)
    hf_rfid.validate_params(readers, "readers")
    if motion_model not in ("omni", "omni_body"):
        raise ValueError(
            f"motion_model must be 'omni' or 'omni_body' (the frame of the odometry), got {motion_model!r}"
        )
    sd = odometry_sd.sd if isinstance(odometry_sd, OmniNoise) else odometry_sd
    check_key(key)
    sd = jnp.asarray(sd)
    check_shape("odometry_sd", sd, (3,))
    check_nonnegative("odometry_sd", sd)
    controls = jnp.asarray(controls)
    if not jnp.issubdtype(controls.dtype, jnp.floating):
        controls = controls.astype(_float_dtype())
    check_shape("controls", controls, (None, 4))
    if controls.shape[0] < 1:
        raise ValueError("controls must hold at least one step")
    check_magnitude("controls", controls)
    # np.asarray first: inside a caller's jit, even a concrete array's slice is traced
    if is_concrete(controls) and not np.all(np.asarray(controls)[:, 3] > 0):
        raise ValueError("controls[:, 3] (Δt) must be > 0 s")
    start_pose = jnp.asarray(start_pose)
    check_shape("start_pose", start_pose, (3,))
    check_magnitude("start_pose", start_pose)
    side = _static_side(readers, footprint_side, "simulate")
    k = _resolve_capacity(carpet.layout, side, readers.offsets, max_detections, "simulate")
    n = candidates_per_axis(carpet.layout, side)
    if kidnap is None:
        kid_step, kid_pose = jnp.asarray(-1, jnp.int32), jnp.zeros(3, controls.dtype)
    else:
        if not isinstance(kidnap, Kidnap):
            raise ValueError(f"kidnap must be a Kidnap(step, pose), got {type(kidnap).__name__}")
        kid_step, kid_pose = jnp.asarray(kidnap.step, jnp.int32), jnp.asarray(kidnap.pose)
        check_shape("kidnap.step", kid_step, ())
        check_shape("kidnap.pose", kid_pose, (3,))
        check_finite("kidnap.pose", kid_pose)
        if is_concrete(kid_step) and not 0 <= int(kid_step) < controls.shape[0]:
            raise ValueError(f"kidnap.step must be in [0, {controls.shape[0]}), got {int(kid_step)}")
    return _simulate_jit(
        key,
        carpet,
        readers.offsets,
        readers.half_width,
        start_pose,
        controls,
        sd,
        kid_step,
        kid_pose,
        motion_model,
        side,
        n,
        k,
    )


def kidnapping_scenario(
    key: jax.Array,
    carpet: TagCarpet,
    readers: hf_rfid.HFReaderParams,
    odometry_sd: Any,
    width: float = 1.0,
    height: float = 1.0,
    start: tuple[float, float] | None = None,
    speed: float = 0.2,
    dt: float = 0.1,
    kidnap_from: float = 0.65,
    kidnap_to: float = 0.15,
    laps_after: int = 1,
    turn_at_corners: bool = True,
    max_detections: int | None = None,
    motion_model: str = "omni",
    footprint_side: float | None = None,
) -> HFRun:
    """The kidnapping experiment of [W] §3.4.3 (Fig. 3.12) on a rectangle.

    The robot drives the rectangle of :func:`jaxnav.sim.trajectories.rectangle_controls` from A
    (``start``) to B, the pose at fraction ``kidnap_from`` of the first lap; at
    the next step it is teleported to C, the pose it had at fraction
    ``kidnap_to < kidnap_from`` of that lap (a place already mapped), and
    drives on from C to the end of the lap and ``laps_after`` more laps (to D).
    Fractions count steps of a lap. ``run.kidnapped`` marks the kidnap step.

    Args:
        start: lower-left corner (m); default the carpet origin + (0.25, 0.25). The other
            arguments are as in :func:`jaxnav.sim.trajectories.rectangle_controls` and
            :func:`simulate`.
    """
    check_key(key)
    if not 0.0 <= float(kidnap_to) < float(kidnap_from) <= 1.0:
        raise ValueError(
            f"need 0 ≤ kidnap_to < kidnap_from ≤ 1 (fractions of the first lap), got {kidnap_to!r}, {kidnap_from!r}"
        )
    if isinstance(laps_after, bool) or not isinstance(laps_after, (int, np.integer)) or laps_after < 0:
        raise ValueError(f"laps_after must be an integer ≥ 0, got {laps_after!r}")
    if start is None:
        start = (carpet.layout.origin[0] + 0.25, carpet.layout.origin[1] + 0.25)
    with jax.ensure_compile_time_eval():  # the lap is built on the host, also when traced under jit/vmap
        start_pose, lap = rectangle_controls(width, height, speed, dt, 1, start, turn_at_corners)
    lap_np = np.asarray(lap, np.float64)
    num = lap_np.shape[0]
    i_b = min(num - 1, max(1, int(round(kidnap_from * num))))
    i_c = min(i_b - 1, int(round(kidnap_to * num)))
    # exact (float64) poses of the lap, P[i] = pose after control i
    poses = np.asarray(start_pose, np.float64)[None, :] + np.cumsum(lap_np[:, :3] * lap_np[:, 3:4], axis=0)
    target = poses[i_c].copy()
    target[2] = (target[2] + math.pi) % (2 * math.pi) - math.pi
    kidnap_row = np.array([[0.0, 0.0, 0.0, lap_np[i_b, 3]]])
    rows = [lap_np[:i_b], kidnap_row, lap_np[i_c + 1 :]] + [lap_np] * int(laps_after)
    controls = jnp.asarray(np.concatenate(rows, axis=0), lap.dtype)
    kid = Kidnap(jnp.asarray(i_b, jnp.int32), jnp.asarray(target, lap.dtype))
    return simulate(
        key, carpet, readers, start_pose, controls, odometry_sd, max_detections, motion_model, kid, footprint_side
    )


# ---------------------------------------------------------------------------
# the carpet as the soft detection likelihood reads it


def tag_map(carpet: TagCarpet, window: float) -> hf_rfid.TagMap:
    """``carpet`` as a :class:`~jaxnav.models.hf_rfid.TagMap` for
    :func:`jaxnav.models.hf_rfid.soft_detection_log_likelihood` with this ``window`` (m).

    ``positions`` looks the tags up by ID (lattice arithmetic plus the jitter); ``near``
    enumerates the lattice candidates of a square of half-width ``window`` around each reader
    (``candidates_per_axis(layout, 2·window)²`` per reader, a static count).
    """
    _check_carpet(carpet)
    w = float(window)
    if not (math.isfinite(w) and w > 0):
        raise ValueError(f"window must be a finite number > 0 m, got {window!r}")
    layout, jitter = carpet.layout, carpet.jitter
    n = candidates_per_axis(layout, 2.0 * w)

    def positions(ids: jax.Array, dtype: Any) -> jax.Array:
        safe = jnp.clip(ids, 0, layout.num_tags - 1)
        ix, iy = tag_indices(layout, safe)
        return _nominal(layout, ix, iy, dtype) + jnp.take(jitter, safe, axis=0)

    def near(pose: jax.Array, offsets: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
        return _candidates(layout, jitter, pose, offsets, w, n)

    return hf_rfid.TagMap(positions, near, jitter.dtype)
