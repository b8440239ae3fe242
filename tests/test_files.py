"""Files that are not what they should be, and writes that fail, through the API and the command line.

1. A data file or a checkpoint that is a named pipe (FIFO), a folder or a device (``/dev/null``,
   ``/dev/zero``) is refused before it is opened, naming the path: never a read that waits forever
   on the pipe or reads a device's endless (or empty) data. A test that could block runs its call
   in a thread with a time limit, so a regression fails instead of hanging.
2. A write that fails (disk full, quota exceeded, read-only, permission denied) names the file and
   its cause, and leaves the file there whole: the checkpoint, the results and the plots are
   written to a temporary file renamed into place.
3. A checkpoint records a SHA-256 of its values: a value edited by hand or damaged is refused with
   ``--fresh`` advised; a checkpoint without one is read with a warning.

Everything runs on small synthetic files in ``tmp_path``; nothing is compiled (the sweeps read
complete checkpoints) except one sweep of a one-line function.
"""

from __future__ import annotations

import errno
import gzip
import json
import os
import re
import subprocess
import sys
import threading
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnav import cli
from jaxnav.experiments import registry
from jaxnav.experiments import sweep as sw
from jaxnav.experiments.hf_slam import ERROR_COLUMNS
from jaxnav.io import _files, adarf, mrclam

needs_fifo = pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no named pipes on this system")
KEY = jax.random.PRNGKey(11)


def _returns_within(call, *fifos, seconds=30.0):
    """``call()``'s value (or its exception), failing the test if it has not returned after ``seconds``:
    a read of a named pipe blocks until a writer comes. Then the pipes are opened for writing once, so
    that the blocked thread gets an end of file and ends."""
    box = {}

    def target():
        try:
            box["value"] = call()
        except BaseException as err:  # handed to the test's thread
            box["error"] = err

    thread = threading.Thread(target=target, daemon=True)
    thread.start()
    thread.join(seconds)
    if thread.is_alive():
        for fifo in fifos:
            try:
                os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
            except OSError:
                pass
        thread.join(5)
        pytest.fail(f"still waiting after {seconds:g} s: a named pipe was opened instead of refused")
    if "error" in box:
        raise box["error"]
    return box["value"]


def _make(kind, path):
    """Put a ``kind`` ("fifo", "folder", "/dev/null", "/dev/zero": a link to it) at ``path``."""
    path = os.fspath(path)
    if os.path.lexists(path):
        os.remove(path)
    if kind == "fifo":
        os.mkfifo(path)
    elif kind == "folder":
        os.mkdir(path)
    else:
        os.symlink(kind, path)
    return path


KINDS = {
    "fifo": "is a named pipe (FIFO), not a regular file",
    "folder": "is a folder, not a regular file",
    "/dev/null": "is a character device, not a regular file",
    "/dev/zero": "is a character device, not a regular file",
}


def _kinds(*names):
    return [pytest.param(k, marks=needs_fifo) if k == "fifo" else k for k in (names or KINDS)]


# ---------------------------------------------------------------------------
# 1. named pipes, folders and devices are refused before they are opened: the helper


@pytest.mark.parametrize("kind", _kinds())
def test_require_regular_names_what_the_path_is(tmp_path, kind):
    path = _make(kind, tmp_path / "file")
    with pytest.raises(ValueError) as err:
        _returns_within(lambda: _files.open_regular(path, "do this").read(10), path)
    assert str(err.value) == f"{path}: {KINDS[kind]}; do this"
    with pytest.raises(ValueError, match=re.escape(KINDS[kind])):
        _files.require_regular(path, "do this", missing_ok=True)
    regular = tmp_path / "regular"
    regular.write_text("text")
    os.symlink(regular, tmp_path / "link")
    assert _files.require_regular(tmp_path / "link", "") and not _files.require_regular(
        tmp_path / "absent", "", missing_ok=True
    )
    with pytest.raises(FileNotFoundError, match="absent"):
        _files.require_regular(tmp_path / "absent", "")


# ---------------------------------------------------------------------------
# ... by the loaders

MRCLAM_FILES = {
    "Barcodes.dat": "# subject barcode\n1 5\n6 63\n7 25\n",
    "Landmark_Groundtruth.dat": "# subject x y sdx sdy\n6 1.0 2.0 0.01 0.01\n7 3.0 1.0 0.01 0.01\n",
    "Robot1_Odometry.dat": "# t v w\n" + "".join(f"{0.1 * i:.1f} 0.1 0.0\n" for i in range(30)),
    "Robot1_Groundtruth.dat": "# t x y theta\n" + "".join(f"{0.1 * i:.1f} {0.01 * i:.2f} 0 0\n" for i in range(30)),
    "Robot1_Measurement.dat": "# t barcode range bearing\n0.05 63 1.5 0.1\n0.15 25 2.0 -0.2\n",
}


def _mrclam(root):
    folder = root / mrclam.DATASET
    folder.mkdir(parents=True)
    for name, text in MRCLAM_FILES.items():
        (folder / name).write_text(text)
    return root


def _adarf_file(p):
    header = "epc,antennaIndex,frequency,time,RSSI,phase,dopplerShift,velocity,x,y,z,angle"
    rows = [
        f"{epc},1,{int(f)},0,-50.5,{0.1 * (t + c) % 6.28:.4f},0,0,{0.02 * (p + 1):.3f},1.63,0,0"
        for t, epc in enumerate(adarf.TARGET_EPCS)
        for c, f in enumerate(adarf.CHANNELS_HZ)
    ]
    return gzip.compress(("\n".join([header, *rows]) + "\n").encode("utf-8-sig"), mtime=0)


def _adarf(root):
    folder = root / adarf.DATASET
    exp = folder / "dataset1_test" / "x"
    exp.mkdir(parents=True)
    (folder / "tag_ground_truth.csv").write_text(
        "experiment,epc,x_m,y_m\n" + "".join(f"x,{e},{0.3 + 0.2 * i},0.8\n" for i, e in enumerate(adarf.TARGET_EPCS))
    )
    for p in range(adarf.NUM_POINTS):
        (exp / f"{p}.csv.gz").write_bytes(_adarf_file(p))
    return root


@pytest.mark.parametrize("kind", _kinds())
@pytest.mark.parametrize("name", ["Robot1_Odometry.dat", "Robot1_Measurement.dat", "Barcodes.dat"])
def test_mrclam_refuses_a_data_file_that_is_not_a_regular_file(tmp_path, name, kind):
    root = _mrclam(tmp_path)
    assert mrclam.load_robot(1, root).odometry.t.shape == (30,)  # the copy is good
    mrclam._load_map.cache_clear()
    mrclam._load_robot.cache_clear()
    path = _make(kind, tmp_path / mrclam.DATASET / name)
    with pytest.raises(ValueError) as err:
        _returns_within(lambda: mrclam.load_robot(1, root), path)
    assert str(err.value).startswith(f"{path}: {KINDS[kind]}; replace it by the dataset's own file"), err.value


@pytest.mark.parametrize("kind", _kinds())
@pytest.mark.parametrize("name", ["tag_ground_truth.csv", "dataset1_test/x/3.csv.gz"])
def test_adarf_refuses_a_data_file_that_is_not_a_regular_file(tmp_path, name, kind):
    root = _adarf(tmp_path)
    path = _make(kind, tmp_path / adarf.DATASET / name)
    with pytest.raises(ValueError) as err:
        _returns_within(lambda: adarf.load_experiment("x", root), path)
    assert str(err.value).startswith(f"{path}: {KINDS[kind]}; replace it by the dataset's own file"), err.value
    if name.endswith(".gz"):  # the experiment is listed, so that loading it says what is wrong
        assert adarf.available_experiments(root) == ("x",)


# ---------------------------------------------------------------------------
# ... by the sweep and the registry


class Run(NamedTuple):
    value: jax.Array
    count: jax.Array


def _fn(key):
    return Run(jax.random.normal(key), jnp.int32(2))


CELLS = [("first", _fn), ("second", _fn)]


def _checkpoint(values=(9.8, 10.1, 9.7, 10.4), signed=True):
    """A complete checkpoint of CELLS with these values, as the sweep writes it (nothing to compute)."""
    from jaxnav import __version__

    meta = {"cells": ["first", "second"], "seed": np.asarray(jax.random.key_data(KEY)).tolist(), "jaxnav": __version__}
    cells = {c: {"value": list(values), "count": [2] * len(values)} for c in ("first", "second")}
    data = {"meta": meta, "chunk_size": 2, "cells": cells}
    if signed:
        data["sha256"] = sw._checksum(data)
    return data


def _sweep(path, **kwargs):
    return sw.sweep(CELLS, 4, KEY, str(path), chunk_size=2, progress=False, **kwargs)


@pytest.mark.parametrize("fresh", [False, True], ids=["resume", "fresh"])
@pytest.mark.parametrize("kind", _kinds("fifo", "folder", "/dev/null"))
def test_a_checkpoint_that_is_not_a_regular_file_is_refused(tmp_path, kind, fresh):
    """Refused before it is read (or, with fresh, before a chunk is computed and written over it)."""
    path = _make(kind, tmp_path / "runs.json")
    with pytest.raises(ValueError) as err:
        _returns_within(lambda: _sweep(path, fresh=fresh), path)
    assert str(err.value) == f"{path}: {KINDS[kind]}; remove it or use another output directory " + (
        "(a checkpoint is a regular JSON file)"
    )
    assert os.path.lexists(path) and not os.path.isfile(path)  # left as it was


@needs_fifo
def test_the_registry_refuses_an_output_that_is_not_a_regular_file_before_computing(tmp_path, monkeypatch):
    def computed(*args, **kwargs):
        raise AssertionError("the sweep ran before the output was refused")

    monkeypatch.setattr(sw, "sweep", computed)
    path = _make("fifo", tmp_path / "table-3.1.quick.md")
    with pytest.raises(ValueError, match=re.escape(f"{path}: is a named pipe (FIFO), not a regular file")):
        _returns_within(lambda: registry.run("table-3.1", 2, KEY, str(tmp_path), quick=True, progress=False), path)


# ---------------------------------------------------------------------------
# 2. a write that fails names the file and leaves it whole


def _leftovers(folder):
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


@pytest.mark.parametrize(
    "code, cause",
    [
        (errno.ENOSPC, "no space left on the device: the disk is full"),
        (errno.EDQUOT, "the disk quota is exceeded"),
        (errno.EROFS, "the file system is read-only"),
        (errno.EACCES, "permission denied"),
    ],
)
def test_a_failed_write_names_the_file_and_keeps_the_old_one(tmp_path, code, cause):
    path = tmp_path / "out.json"
    path.write_text("the previous content")

    def half_then_fail(f):
        f.write('{"runs": [1, 2')
        raise OSError(code, os.strerror(code))

    with pytest.raises(OSError) as err:
        _files.write_atomic(path, half_then_fail, note="what was kept")
    assert err.value.errno == code and err.value.filename == str(path)
    message = str(err.value)
    assert message.startswith(f"{path}: cannot be written ({cause}); ") and message.endswith("; what was kept")
    assert "\n" not in message
    assert path.read_text() == "the previous content" and _leftovers(tmp_path) == []


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="no /dev/full")
def test_a_real_disk_full_error_is_named(tmp_path, monkeypatch):
    """/dev/full answers every write with ENOSPC: the temporary file is swapped for it."""
    path = tmp_path / "out.json"

    def full(real, suffix):
        tmp = os.path.join(os.path.dirname(real), ".out.json.x.tmp")
        open(tmp, "w").close()
        return os.open("/dev/full", os.O_WRONLY), tmp

    monkeypatch.setattr(_files, "_temporary", full)
    with pytest.raises(OSError) as err:
        _files.write_atomic(path, lambda f: f.write("x" * 100_000))
    assert err.value.errno == errno.ENOSPC and str(err.value).startswith(f"{path}: cannot be written (no space left")
    assert not path.exists() and _leftovers(tmp_path) == []


def test_a_symbolic_link_is_written_through(tmp_path):
    target = tmp_path / "real.json"
    target.write_text("old")
    os.symlink(target, tmp_path / "link.json")
    _files.write_atomic(tmp_path / "link.json", lambda f: f.write("new"))
    assert os.path.islink(tmp_path / "link.json") and target.read_text() == "new"


def _fail_dump_after(calls, code=errno.ENOSPC):
    """A ``json.dump`` that writes half its text, then fails like a full disk, from call ``calls`` on."""
    real = json.dump
    seen = []

    def dump(obj, fp, **kwargs):
        seen.append(1)
        if len(seen) < calls:
            return real(obj, fp, **kwargs)
        text = json.dumps(obj, **kwargs)
        fp.write(text[: len(text) // 2])
        raise OSError(code, os.strerror(code))

    return dump


def test_a_full_disk_keeps_the_checkpoint_of_the_chunks_saved_before(tmp_path, monkeypatch):
    """The second chunk's save fails half-way: the error names the checkpoint, which still holds the first
    chunk, whole and resumable, and no temporary file is left behind."""
    path = tmp_path / "runs.json"
    monkeypatch.setattr(json, "dump", _fail_dump_after(2))
    with pytest.raises(OSError) as err:
        sw.sweep([("first", _fn)], 4, KEY, str(path), chunk_size=2, progress=False)
    message = str(err.value)
    assert err.value.errno == errno.ENOSPC and message.startswith(f"{path}: cannot be written (no space left")
    assert message.endswith(
        "the checkpoint keeps the chunks saved before: run the same command again to resume from them"
    )
    saved = json.loads(path.read_text())
    assert len(saved["cells"]["first"]["value"]) == 2 and saved["sha256"] == sw._checksum(saved)
    assert _leftovers(tmp_path) == []
    monkeypatch.undo()
    seen = []
    out = sw.sweep(
        [("first", _fn)], 4, KEY, str(path), chunk_size=2, progress=False, on_chunk=lambda c, d: seen.append(d)
    )
    assert seen == [4] and out["first"]["value"].shape == (4,)


def _table_checkpoint(folder, edit=None, signed=True):
    """A complete checkpoint of the quick table-3.1 (2 runs a cell: nothing to compute)."""
    from jaxnav import __version__

    cells = registry.get("table-3.1").cells(True)
    meta = {
        "cells": [c.id for c in cells],
        "seed": np.asarray(jax.random.key_data(jax.random.PRNGKey(0))).tolist(),  # --seed 0
        "jaxnav": __version__,
        "experiment": "table-3.1",
        "quick": True,
    }
    data = {"meta": meta, "chunk_size": 2, "cells": {c.id: {col: [9.8, 10.2] for col in ERROR_COLUMNS} for c in cells}}
    if signed:
        data["sha256"] = sw._checksum(data)
    if edit:
        edit(data)
    path = folder / "table-3.1.quick.runs.json"
    path.write_text(json.dumps(data))
    return path


def _fail_fsync_of(marker, monkeypatch):
    """``os.fsync`` fails like a full disk for a file whose name holds ``marker`` (a file system with
    delayed allocation reports a full disk when the data are flushed)."""
    real = os.fsync

    def fsync(fd):
        if marker in os.path.basename(os.readlink(f"/proc/self/fd/{fd}")):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real(fd)

    monkeypatch.setattr(os, "fsync", fsync)


@pytest.mark.skipif(not os.path.isdir("/proc/self/fd"), reason="needs /proc/self/fd")
def test_the_results_are_written_whole_or_not_at_all(tmp_path, monkeypatch):
    """The Markdown table cannot be written: the error names it, the previous one is kept whole."""
    _table_checkpoint(tmp_path)
    (tmp_path / "table-3.1.quick.md").write_text("the previous table\n")
    _fail_fsync_of(".quick.md.", monkeypatch)
    with pytest.raises(OSError) as err:
        registry.run("table-3.1", 2, jax.random.PRNGKey(0), str(tmp_path), quick=True, progress=False, plot=False)
    assert str(err.value).startswith(f"{tmp_path / 'table-3.1.quick.md'}: cannot be written (no space left")
    assert "the runs are kept in" in str(err.value)
    assert (tmp_path / "table-3.1.quick.md").read_text() == "the previous table\n" and _leftovers(tmp_path) == []
    assert json.loads((tmp_path / "table-3.1.quick.json").read_text())["runs"] == 2  # written before


# ---------------------------------------------------------------------------
# 3. a checkpoint carries a checksum of its values


def test_a_checkpoint_records_the_checksum_of_its_values(tmp_path):
    """Written by the sweep: the SHA-256 of the canonical JSON of meta, chunk_size and cells; it does not
    depend on the file's layout, so a re-indented checkpoint still reads."""
    path = tmp_path / "runs.json"
    sw.sweep([("first", _fn)], 2, KEY, str(path), chunk_size=2, progress=False)
    data = json.loads(path.read_text())
    assert list(data) == ["meta", "chunk_size", "cells", "sha256"]
    canonical = json.dumps({k: data[k] for k in ("meta", "chunk_size", "cells")}, sort_keys=True, separators=(",", ":"))
    import hashlib

    assert data["sha256"] == hashlib.sha256(canonical.encode()).hexdigest()
    path.write_text(json.dumps(dict(reversed(list(data.items()))), indent=4))
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no warning: the checksum matches
        out = sw.sweep([("first", _fn)], 2, KEY, str(path), chunk_size=2, progress=False)
    assert out["first"]["value"].tolist() == data["cells"]["first"]["value"]


def _edit_value(data):
    data["cells"]["first"]["value"][2] = 12509.0


EDITS = {
    "edited-value": (_edit_value, "its values do not match its sha256 checksum"),
    "edited-chunk-size": (lambda d: d.update(chunk_size=4), "its values do not match its sha256 checksum"),
    "damaged-digit": (
        lambda d: d["cells"]["second"]["count"].__setitem__(0, 3),
        "its values do not match its sha256 checksum",
    ),
    "checksum-not-hex": (lambda d: d.update(sha256="xyz"), "its sha256 is 'xyz', not a SHA-256 digest"),
    "checksum-a-number": (lambda d: d.update(sha256=7), "its sha256 is 7, not a SHA-256 digest"),
}


@pytest.mark.parametrize("case", list(EDITS), ids=list(EDITS))
def test_an_edited_checkpoint_is_refused_naming_the_file_and_fresh(tmp_path, case):
    """9.8 mm edited into 12,509 mm would move the cell's mean from 10 to 3137 mm: refused instead."""
    edit, reason = EDITS[case]
    data = _checkpoint()
    edit(data)
    path = tmp_path / "runs.json"
    path.write_text(json.dumps(data))
    before = path.read_bytes()
    with pytest.raises(ValueError) as err:
        _sweep(path)
    message = str(err.value)
    assert message.startswith(f"{path}: ") and reason in message and "\n" not in message, message
    assert message.endswith("pass --fresh (fresh=True) to discard it and start again"), message
    assert path.read_bytes() == before


def test_an_unchanged_checkpoint_reads_and_fresh_replaces_an_edited_one(tmp_path):
    path = tmp_path / "runs.json"
    path.write_text(json.dumps(_checkpoint()))
    assert _sweep(path)["first"]["value"].tolist() == [9.8, 10.1, 9.7, 10.4]
    data = _checkpoint()
    _edit_value(data)
    path.write_text(json.dumps(data))
    out = _sweep(path, fresh=True)
    assert np.all(np.abs(out["first"]["value"]) < 10)  # recomputed: normal draws
    written = json.loads(path.read_text())
    assert written["sha256"] == sw._checksum(written)


def test_a_checkpoint_without_a_checksum_is_read_with_a_warning(tmp_path):
    """Written before checkpoints recorded one (like the committed full-size ones): its values cannot be
    checked, so it is read as it is, with a warning naming it and --fresh."""
    path = tmp_path / "runs.json"
    path.write_text(json.dumps(_checkpoint(signed=False)))
    with pytest.warns(sw.UnverifiedCheckpointWarning, match=re.escape(str(path)) + ".*no sha256.*--fresh"):
        out = _sweep(path)
    assert out["first"]["value"].tolist() == [9.8, 10.1, 9.7, 10.4]


# ---------------------------------------------------------------------------
# the command line: one line on stderr, exit status 2, never a traceback


def _main(argv, capsys):
    try:
        code = cli.main(argv)
    except SystemExit as stop:
        code = stop.code
    out, err = capsys.readouterr()
    return code, out, err


def _refused(code, err, command, pattern):
    assert code == 2 and "Traceback" not in err, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"jaxnav {command}: error: "), err
    assert re.search(pattern, lines[0]), lines[0]


@pytest.fixture
def nothing_computed(monkeypatch):
    def computed(*args, **kwargs):
        raise AssertionError("the command computed before refusing its input")

    from jaxnav import demo
    from jaxnav.experiments import mrclam as mrclam_xp

    for module, name in [(demo, "run_demo"), (registry, "run"), (mrclam_xp, "run_robot")]:
        monkeypatch.setattr(module, name, computed)


@pytest.mark.parametrize("kind", _kinds("fifo", "/dev/null"))
def test_the_cli_refuses_an_output_that_is_not_a_regular_file(tmp_path, kind, capsys, nothing_computed):
    path = _make(kind, tmp_path / "plot.png")
    code, _, err = _returns_within(lambda: _main(["demo", "--out", path], capsys), path)
    _refused(code, err, "demo", re.escape(f"--out {path!r}: {path} {KINDS[kind]}; remove it or choose another --out"))


@needs_fifo
def test_the_cli_refuses_a_checkpoint_that_is_a_named_pipe(tmp_path, capsys, nothing_computed):
    path = _make("fifo", tmp_path / "table-3.1.quick.runs.json")
    argv = ["experiments", "run", "table-3.1", "--quick", "--runs", "2", "--out", str(tmp_path), "--no-progress"]
    code, _, err = _returns_within(lambda: _main(argv, capsys), path)
    _refused(code, err, "experiments", re.escape(f"{path} is a named pipe (FIFO), not a regular file; remove it"))


@needs_fifo
def test_the_cli_refuses_a_data_file_that_is_a_named_pipe(tmp_path, capsys):
    root = _mrclam(tmp_path)
    path = _make("fifo", tmp_path / mrclam.DATASET / "Robot1_Odometry.dat")
    argv = ["mrclam", "--robots", "1", "--data", str(root), "--out", ""]
    code, _, err = _returns_within(lambda: _main(argv, capsys), path)
    _refused(code, err, "mrclam", re.escape(f"{path}: is a named pipe (FIFO), not a regular file; replace it"))
    adarf_root = _adarf(tmp_path / "adarf")
    path = _make("/dev/zero", tmp_path / "adarf" / adarf.DATASET / "dataset1_test" / "x" / "7.csv.gz")
    code, _, err = _main(["uhf-real", "--data", str(adarf_root), "--experiment", "x", "--out", ""], capsys)
    _refused(code, err, "uhf-real", re.escape(f"{path}: is a character device, not a regular file; replace it"))


def test_the_cli_names_a_plot_that_cannot_be_written(tmp_path, capsys, monkeypatch):
    """The disk fills while the PNG is written: one line naming it; the previous PNG is kept."""
    from jaxnav import demo

    fake = demo.DemoResult(*(np.zeros((2, 3)),) * 2, np.zeros(2), np.zeros((1, 2)), 0.25)
    monkeypatch.setattr(demo, "run_demo", lambda **kwargs: fake)

    def plot(result, path):
        with open(path, "wb") as fh:
            fh.write(b"\x89PNG half")
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(demo, "plot_demo", plot)
    path = tmp_path / "demo.png"
    path.write_bytes(b"the previous plot")
    code, out, err = _main(["demo", "--steps", "2", "--out", str(path)], capsys)
    _refused(code, err, "demo", re.escape(f"{path}: cannot be written (no space left on the device: the disk is full)"))
    assert path.read_bytes() == b"the previous plot" and _leftovers(tmp_path) == []


@pytest.mark.skipif(not os.path.isdir("/proc/self/fd"), reason="needs /proc/self/fd")
def test_the_cli_names_a_checkpoint_edited_by_hand_or_results_it_cannot_write(tmp_path, capsys, monkeypatch):
    argv = ["experiments", "run", "table-3.1", "--quick", "--runs", "2", "--seed", "0", "--out", str(tmp_path)]
    argv += ["--no-progress"]

    def edit(data):
        data["cells"]["16|pf_slam|0"]["dr_mm"][0] = 12509.0

    path = _table_checkpoint(tmp_path, edit)
    code, _, err = _main(argv, capsys)
    _refused(code, err, "experiments", re.escape(f"{path}: its values do not match its sha256 checksum") + ".*--fresh")

    _table_checkpoint(tmp_path)
    _fail_fsync_of(".quick.json.", monkeypatch)
    code, _, err = _main(argv, capsys)
    _refused(code, err, "experiments", re.escape(f"{tmp_path / 'table-3.1.quick.json'}: cannot be written (no space"))


def test_the_cli_warns_in_one_line_about_a_checkpoint_without_a_checksum(tmp_path, capsys):
    path = _table_checkpoint(tmp_path, signed=False)
    argv = ["experiments", "run", "table-3.1", "--quick", "--runs", "2", "--out", str(tmp_path), "--no-progress"]
    code, out, err = _main(argv, capsys)
    assert code == 0 and "Traceback" not in err, err
    warned = [line for line in err.splitlines() if "warning" in line]
    assert len(warned) == 1 and warned[0].startswith(
        f"jaxnav experiments: warning: {path}: the checkpoint has no sha256"
    )
    assert "wrote" in out


@needs_fifo
def test_no_traceback_and_no_wait_as_a_user_runs_it(tmp_path):
    """As a user runs it: a named pipe in the checkpoint's place is refused at once (it once waited forever)."""
    path = _make("fifo", tmp_path / "table-3.1.quick.runs.json")
    try:
        run = subprocess.run(
            [sys.executable, "-m", "jaxnav.cli", "experiments", "run", "table-3.1", "--quick", "--runs", "2"]
            + ["--out", str(tmp_path), "--no-progress"],
            capture_output=True,
            text=True,
            timeout=120,
        )
    except subprocess.TimeoutExpired:  # the child is killed
        pytest.fail("the command waited on the named pipe")
    _refused(run.returncode, run.stderr, "experiments", re.escape(f"{path} is a named pipe (FIFO)"))
