#!/usr/bin/env python3
"""A hostile-input battery for the ``fingerloc`` command line; not part of CI (the suite has its own tests).

Runs each case through the real entry point in a subprocess (memory bounded
by ``HOSTILE_MEMORY_LIMIT``, each case with a time limit) and counts the clean
outcomes: a case meant to fail is clean when the command exits with 2 and
prints exactly one line ``error: ...`` on stderr (no traceback), and, where it
names files, leaves them byte-identical (a FIFO a FIFO, a link a link); a case
meant to succeed is clean when it exits with 0 and its check holds (literal
labels, strict JSON, no lost place, a warning said, ...).

Categories: usage errors, hostile JSON Lines, output paths, crafted
databases, images, option ranges, failed commands that must change nothing,
files that are not sensor files, strict JSON, database mechanics (the first
battery); and data loss (the writer protocol: learn into a map, track with a
concurrent learn, a WAL file, devices, FIFOs and link loops as outputs),
what does not fit (another modality, another frame, degenerate runs and
maps), loaded values checked (crafted calibrations, positions, lambdas,
hashes, flipped bytes), faults (file-size limit, full device, closed pipe,
long names), bounded readers (FIFOs, NUL files, /dev/zero, giant lines,
gzip of blank lines, held locks, tall thin images), images read as meant
(16-bit, EXIF orientation, truncated), bags (damaged messages, a mount at
inf, no usable scan, merged lidars keeping a beacon).

Usage::

    python scripts/hostile.py                 # the fingerloc of this checkout (src/)
    python scripts/hostile.py --src OTHER/src # another version, e.g. an older commit's
    python scripts/hostile.py -v              # print every case
    python scripts/hostile.py -k bag          # only the cases whose name holds "bag"

Prints ``clean N of M`` and exits 0 when every case is clean, else 1.
"""

from __future__ import annotations

import argparse
import gzip
import json
import math
import os
import shutil
import sqlite3
import struct
import subprocess
import sys
import tempfile
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent


#: Address-space bound of each command (bytes): an unbounded allocation fails instead of swapping the machine.
MEMORY_LIMIT = int(os.environ.get("HOSTILE_MEMORY_LIMIT", 6 * 2**30))


def _limit_memory() -> None:
    import resource

    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))


def _state(p: Path) -> object:
    """What must not change about a file: its kind (a FIFO, a link, a device) and a regular file's bytes."""
    import stat as st

    try:
        m = os.lstat(p)
    except FileNotFoundError:
        return None
    if st.S_ISLNK(m.st_mode):
        return ("link", os.readlink(p))
    if st.S_ISREG(m.st_mode):
        return ("file", p.read_bytes())
    return ("kind", st.S_IFMT(m.st_mode))


@dataclass
class Result:
    code: int
    out: str
    err: str


class Battery:
    def __init__(self, src: Path, work: Path, verbose: bool, only: str = "") -> None:
        self.src = src
        self.work = work
        self.verbose = verbose
        self.only = only
        self.results: list[tuple[str, bool, str]] = []

    def run(
        self,
        *args: object,
        timeout: float = 180.0,
        env: dict[str, str] | None = None,
        stdout: Any = subprocess.PIPE,
        fsize: int | None = None,
    ) -> Result:
        e = {**os.environ, "PYTHONPATH": str(self.src), **(env or {})}
        cmd = [sys.executable, "-c", "from fingerloc.cli import main; main()", *map(str, args)]

        def limits() -> None:
            _limit_memory()
            if fsize is not None:
                import resource

                resource.setrlimit(resource.RLIMIT_FSIZE, (fsize, fsize))

        try:
            p = subprocess.run(
                cmd, stdout=stdout, stderr=subprocess.PIPE, timeout=timeout, cwd=self.work, env=e, preexec_fn=limits
            )
        except subprocess.TimeoutExpired:
            return Result(-9, "", "timeout")
        out = p.stdout.decode("utf-8", "replace") if isinstance(p.stdout, bytes) else ""
        return Result(p.returncode, out, p.stderr.decode("utf-8", "replace"))

    def wanted(self, name: str) -> bool:
        return not self.only or self.only.lower() in name.lower() or "(setup" in name

    def record(self, name: str, ok: bool, why: str = "") -> None:
        self.results.append((name, ok, why))
        if self.verbose or not ok:
            print(f"{'ok  ' if ok else 'FAIL'} {name}" + (f"  ({why})" if why and not ok else ""), flush=True)

    def expect_error(
        self,
        name: str,
        *args: object,
        needle: str = "",
        db: Path | None = None,
        keep: tuple[Path, ...] = (),
        notes: int = 0,
        timeout: float = 180.0,
        **run: Any,
    ) -> None:
        """A failure: exit 2 and one ``error:`` line (after ``notes`` lines, e.g. a lock's wait), files kept."""
        if not self.wanted(name):
            return
        watched = [p for p in (db, *keep) if p is not None]
        before = {p: _state(p) for p in watched}
        r = self.run(*args, timeout=timeout, **run)
        lines = r.err.strip().splitlines()
        why = ""
        if r.code != 2:
            why = f"exit {r.code}" + (f": {r.err.strip()[-160:]!r}" if r.code != -9 else " (timeout)")
        elif len(lines) != notes + 1 or not lines[-1].startswith("error: "):
            why = f"stderr not one error line: {r.err.strip()[-200:]!r}"
        elif needle and needle.lower() not in lines[-1].lower():
            why = f"message lacks {needle!r}: {lines[-1]!r}"
        else:
            changed = [p.name for p in watched if _state(p) != before[p]]
            if changed:
                why = f"changed: {', '.join(changed)}"
        self.record(name, not why, why)

    def expect_ok(self, name: str, *args: object, check: Callable[[Result], str] | None = None, **run: Any) -> Result:
        if not self.wanted(name):
            return Result(0, "", "")
        r = self.run(*args, **run)
        why = "" if r.code == 0 else f"exit {r.code}: {r.err.strip()[-200:]!r}"
        if not why and check is not None:
            why = check(r)
        self.record(name, not why, why)
        return r

    def expect_warning(self, name: str, *args: object, needle: str, **run: Any) -> Result:
        """An answer with a doubt: exit 0 and a ``warning:`` line holding ``needle``."""
        def check(r: Result) -> str:
            ok = any(x.startswith("warning: ") and needle.lower() in x.lower() for x in r.err.splitlines())
            return "" if ok else f"no warning with {needle!r}: {r.err.strip()[-200:]!r}"

        return self.expect_ok(name, *args, check=check, **run)


def _places_file(path: Path, labels: list[str], *, poses: bool = True, offset: int = 0) -> Path:
    lines = []
    for k, lab in enumerate(labels):
        for j in range(3):
            ve = [(10 + 37 * (k + offset) + 40 * i + 2 * j) % 360 for i in range(5)]
            rec: dict[str, object] = {"place": lab, "features": {"VE": ve, "c": [ve[0] + 5, ve[2] + 7]}}
            if poses:
                rec["pose"] = [2.0 * k + 0.1 * j, 0.0, 0.0]
            lines.append(json.dumps(rec))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def _box_ranges(w: float, h: float, x: float, y: float, th: float, n: int = 181) -> list[float]:
    out = []
    for i in range(n):
        a = th - math.pi / 2 + math.pi * i / (n - 1)
        dx, dy = math.cos(a), math.sin(a)
        ts = []
        if dx > 1e-12:
            ts.append((w - x) / dx)
        if dx < -1e-12:
            ts.append(-x / dx)
        if dy > 1e-12:
            ts.append((h - y) / dy)
        if dy < -1e-12:
            ts.append(-y / dy)
        out.append(min(min(ts), 30.0))
    return out


def _carmen_log(path: Path, *, scans: int | None = None) -> Path:
    rooms = [(4.0, 3.0), (6.0, 2.5), (3.0, 3.0)]
    lines = ["# synthetic", "PARAM robot_front_laser_max 30 nohost 0"]
    steps = [(w, h, w / 2 + dx, h / 2, 0.3 * dx) for _ in range(2) for (w, h) in rooms for dx in (-0.3, 0.0, 0.3)]
    if scans is not None:
        steps = steps[:scans]
    for k, (w, h, x, y, th) in enumerate(steps):
        r = " ".join(f"{v:.3f}" for v in _box_ranges(w, h, x, y, th))
        wx = x + 20.0 * [r_[0] for r_ in rooms].index(w)
        lines.append(f"FLASER 181 {r} {wx:.3f} {y:.3f} {th:.4f} 0 0 0 {k}.0 host {k}.0")
        lines.append(f"ODOM {wx:.3f} {y:.3f} {th:.4f} 0 0 0 {k}.0 host {k}.0")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def _png(path: Path, w: int, h: int) -> Path:
    def chunk(t: bytes, d: bytes) -> bytes:
        return struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d) & 0xFFFFFFFF)

    ihdr = struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0" * 64)) + chunk(b"IEND", b""))
    return path


def _strict_json(text: str) -> object:
    def bad(name: str) -> object:
        raise ValueError(f"{name} is not JSON")

    return json.loads(text, parse_constant=bad)


CRAFTED = {
    "medoid out of range": "UPDATE places SET medoid = 99",
    "medoid as text": "UPDATE places SET medoid = 'x'",
    "observation of a missing place": "UPDATE observations SET place_id = 77 WHERE id = 1",
    "mixture of a missing place": "UPDATE mixtures SET place_id = 55 WHERE rowid = 1",
    "params as a JSON list": "UPDATE meta SET value = '[1, 2]' WHERE key = 'params'",
    "bearings as TEXT": "UPDATE fingerprints SET bearings = 'abc'",
    "consensus bearings as TEXT": "UPDATE places SET consensus_letters = 'vn', consensus_bearings = 'x'",
    "no observation rows": "DELETE FROM observations",
    "graph counts as text": "INSERT INTO graph_edges VALUES ('a', 'b', 'many')",
    "lambdas as a string": "UPDATE meta SET value = '\"x\"' WHERE key = 'lambdas'",
    "record not JSON": "UPDATE observations SET record = '{' WHERE id = 1",
    "record nested deep": "UPDATE observations SET record = '" + "[" * 5000 + "]" * 5000 + "' WHERE id = 1",
    "letters outside the alphabet": "UPDATE fingerprints SET letters = '!!' WHERE rowid = 1",
}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--src", type=Path, default=HERE.parent / "src", help="the fingerloc source tree to test")
    ap.add_argument("-v", "--verbose", action="store_true")
    ap.add_argument("-k", dest="only", default="", help="only the cases whose name holds this text")
    ap.add_argument("--first-only", action="store_true", help="only the first battery")
    ap.add_argument("--second-only", action="store_true", help="only the second battery")
    args = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="fingerloc-hostile-"))
    first = second = 0
    try:
        b = Battery(args.src.resolve(), work, args.verbose, args.only)
        if not args.second_only:
            battery(b, work)
        first = len(b.results)
        if not args.first_only:
            from hostile2 import battery2

            battery2(b, work)
        second = len(b.results) - first
    finally:
        shutil.rmtree(work, ignore_errors=True)
    for label, part in (("first battery", b.results[:first]), ("second battery", b.results[first:])):
        if part:
            print(f"{label}: clean {sum(ok for _, ok, _ in part)} of {len(part)}")
    del second
    clean = sum(ok for _, ok, _ in b.results)
    print(f"clean {clean} of {len(b.results)}")
    return 0 if clean == len(b.results) else 1


def battery(b: Battery, w: Path) -> None:
    train = _places_file(w / "train.jsonl", ["a", "b", "c"])
    db = w / "p.sqlite"
    # the paper's program: every table of the database has rows to craft
    b.expect_ok("learn (setup)", "learn", train, "--db", db, "--preset", "paper")
    log = _carmen_log(w / "rooms.log")

    # -- usage errors
    b.expect_error("unknown option", "learn", "--bogus")
    b.expect_error("missing argument", "learn")
    b.expect_error("option not an integer", "localize", train, "--db", db, "--top", "many")
    b.expect_error("unknown command", "nosuchcommand")
    b.expect_error("non-UTF-8 argument", "fingerprint", "bad\udcff.jsonl")

    # -- markup and surrogates in user strings
    for label in ("[/x]", "[red]b[/red]"):
        data = _places_file(w / "m.jsonl", [label, "plain"])
        mdb = w / f"m{len(label)}.sqlite"
        b.expect_ok(f"learn with label {label}", "learn", data, "--db", mdb)
        b.expect_ok(f"places with label {label}", "places", "--db", mdb,
                    check=lambda r, lab=label: "" if lab in r.out else "label not printed literally")  # fmt: skip
        b.expect_ok(f"localize with label {label}", "localize", data, "--db", mdb,
                    check=lambda r, lab=label: "" if lab in r.out else "label not printed literally")  # fmt: skip
    mk = w / "[bold]m.sqlite"
    b.expect_ok("markup in a path", "learn", train, "--db", mk,
                check=lambda r: "" if "[bold]m.sqlite" in r.err else "path not printed literally")  # fmt: skip

    # -- hostile JSON Lines in all four commands
    hostile = {
        "400-digit bearing": '{"features": {"VE": [' + "9" * 400 + "]}}",
        "5000-digit bearing": '{"features": {"VE": [' + "9" * 5000 + "]}}",
        "100000-deep nesting": "[" * 100_000 + "]" * 100_000,
        "lone surrogate label": '{"place": "\\ud800", "features": {}}',
        "huge pose": '{"pose": [1e308, -1e308, 0], "features": {"VE": [1]}}',
    }
    for name, line in hostile.items():
        f = w / "h.jsonl"
        f.write_text(line + "\n", encoding="utf-8")
        b.expect_error(f"fingerprint: {name}", "fingerprint", f)
        hdb = w / "h.sqlite"
        if hdb.exists():
            hdb.unlink()
        b.expect_error(f"learn: {name}", "learn", f, "--db", hdb)
        b.expect_error(f"localize: {name}", "localize", f, "--db", db, db=db)
        b.expect_error(f"track: {name}", "track", f, "--db", db, db=db)

    # -- output paths
    (w / "adir").mkdir()
    for name, out in (("missing directory", w / "nope" / "o.json"), ("a directory", w / "adir")):
        r = b.run("localize", train, "--db", db, "--json", out)
        lines = r.err.strip().splitlines()
        ok = r.code == 2 and len(lines) == 1 and lines[0].startswith("error:") and r.out == ""
        b.record(f"localize --json into {name} (checked first)", ok, r.err[-200:])
        b.record(f"no .tmp left after --json into {name}", not list(w.glob("**/*.tmp")), "tmp file left")
    if os.geteuid() != 0:
        ro = w / "ro"
        ro.mkdir()
        ro.chmod(0o500)
        b.expect_error("localize --json into a read-only directory", "localize", train, "--db", db, "--json", ro / "o.json")
    b.expect_error("bench carmen --plot into a missing directory", "bench", "carmen", log, "--plot", w / "nope" / "p.png")
    b.expect_error("demo --out onto a file", "demo", "--quick", "--out", train)

    # -- crafted databases
    for name, sql in CRAFTED.items():
        cdb = w / "crafted.sqlite"
        shutil.copyfile(db, cdb)
        with sqlite3.connect(cdb) as con:
            con.execute("DELETE FROM graph_edges")
            cols = [r[1] for r in con.execute("PRAGMA table_info(observations)")]
            con.execute(sql if "record" in cols else sql.replace("SET record =", "SET data ="))  # schema 3 on
        con.close()
        cmd = ("track", train, "--db", cdb) if "graph" in name else ("localize", train, "--db", cdb)
        b.expect_error(f"crafted database: {name}", *cmd)
    # no fingerprint rows is not an error: the fingerprint term computes them again from the stored observations
    cdb = w / "crafted.sqlite"
    shutil.copyfile(db, cdb)
    with sqlite3.connect(cdb) as con:
        con.execute("DELETE FROM fingerprints")
    con.close()
    b.expect_ok("crafted database: no fingerprint rows (recomputed)", "localize", train, "--db", cdb)
    b.expect_error("a directory at --db", "places", "--db", w / "adir", needle="directory")
    b.expect_error("track LOG --db learned from JSON Lines", "track", log, "--db", db, db=db)

    # -- images, option ranges
    b.expect_error("20000x20000 PNG", "features", _png(w / "b20.png", 20000, 20000))
    b.expect_error("13000x13000 PNG", "features", _png(w / "b13.png", 13000, 13000))
    b.expect_error("--radii 10 inf", "features", w / "b13.png", "--kind", "omni", "--center", "1", "1", "--radii", "10", "inf")
    b.expect_error("reproduce table1 --trials 1e12", "reproduce", "table1", "--trials", "1000000000000")
    b.expect_error("fingerprint --empty-step-deg 1e-9", "fingerprint", train, "--empty-step-deg", "1e-9")
    b.expect_error("learn -k 0", "learn", train, "--db", w / "k0.sqlite", "-k", "0", needle="--components")

    # -- failed commands leave the database byte-identical
    b.expect_error("track --graph-from --filter pose --seed -1", "track", train, "--db", db, "--graph-from", train,
                   "--filter", "pose", "--seed", "-1", db=db)  # fmt: skip
    huge = w / "huge.jsonl"
    huge.write_text("\n".join(
        json.dumps({**json.loads(x), "pose": [1e308, -1e308, 0.0]}) for x in train.read_text().splitlines()
    ) + "\n")  # fmt: skip
    b.expect_error("track --graph-from with poses of 1e308", "track", train, "--db", db, "--graph-from", huge,
                   "--filter", "pose", db=db)  # fmt: skip
    one = _places_file(w / "one.jsonl", ["a"])
    b.expect_error("track --graph-from, --filter pose on one place", "track", one, "--db", db, "--graph-from", one,
                   "--filter", "pose", db=db)  # fmt: skip
    b.expect_error("track --map --db EXISTING", "track", log, "--db", db, "--map", db=db)
    b.expect_ok("track --graph-from (stores the graph)", "track", train, "--db", db, "--graph-from", train, "-q")

    # -- not a sensor file
    (w / "r.log").write_bytes(os.urandom(5000))
    (w / "r.log.gz").write_bytes(os.urandom(5000))
    (w / "e.log").write_bytes(b"")
    (w / "n.log").write_text("ODOM 1 2 3 0 0 0 1 host 1\n")
    with gzip.open(w / "t.log.gz", "wb") as gz:
        gz.write(os.urandom(3000))
    for name in ("r.log", "r.log.gz", "e.log", "n.log", "t.log.gz"):
        b.expect_error(f"features on {name}", "features", w / name)

    # -- strict JSON
    one_scan = _carmen_log(w / "one-scan.log", scans=1)
    bj = w / "bench.json"
    r = b.run("bench", "carmen", one_scan, "--json", bj, "-m", "baseline-histogram")
    if r.code == 0:
        try:
            _strict_json(bj.read_text())
            b.record("bench carmen on a one-scan log: strict JSON", True)
        except ValueError as err:
            b.record("bench carmen on a one-scan log: strict JSON", False, str(err))
    else:
        lines = r.err.strip().splitlines()
        b.record("bench carmen on a one-scan log: strict JSON", r.code == 2 and len(lines) == 1, r.err[-200:])

    # -- more files and options that are wrong
    (w / "bin.jsonl").write_bytes(os.urandom(2000))
    (w / "zero.sqlite").write_bytes(b"")
    (w / "text.sqlite").write_text("not a database\n")
    (w / "text.png").write_text("not an image\n")
    (w / "trunc.sqlite").write_bytes(db.read_bytes()[:3000])
    for name, args in {
        "fingerprint on a directory": ("fingerprint", w / "adir"),
        "fingerprint on a missing file": ("fingerprint", w / "missing.jsonl"),
        "fingerprint on binary data": ("fingerprint", w / "bin.jsonl"),
        "learn on an empty file": ("learn", w / "e.log", "--db", w / "e.sqlite"),
        "localize with a zero-byte database": ("localize", train, "--db", w / "zero.sqlite"),
        "localize with a text file as database": ("localize", train, "--db", w / "text.sqlite"),
        "localize with a truncated database": ("localize", train, "--db", w / "trunc.sqlite"),
        "localize with JSON Lines as database": ("localize", train, "--db", train),
        "localize --top 0": ("localize", train, "--db", db, "--top", "0"),
        "learn --terms XX": ("learn", train, "--db", w / "t.sqlite", "--terms", "XX"),
        "learn --weights VE=-1": ("learn", train, "--db", w / "t.sqlite", "--weights", "VE=-1"),
        "learn --unknown-prior 2": ("learn", train, "--db", w / "t.sqlite", "--unknown-prior", "2"),
        "learn a different -k into an existing database": ("learn", train, "--db", db, "-k", "2"),
        "track --scale inf": ("track", train, "--db", db, "--scale", "inf"),
        "track --odometry-error nan": ("track", train, "--db", db, "--odometry-error", "nan"),
        "track --observe sometimes": ("track", train, "--db", db, "--observe", "sometimes"),
        "track on a bag name": ("track", w / "x.bag", "--db", db),
        "bench carmen without a log": ("bench", "carmen"),
        "bench carmen on a missing log": ("bench", "carmen", w / "missing.log"),
        "bench kidnap --filter wheels": ("bench", "kidnap", log, "--filter", "wheels"),
        "reproduce robot --trials 0": ("reproduce", "robot", "--trials", "0"),
        "features --kind nope": ("features", log, "--kind", "nope"),
        "features --band 0.8 0.2": ("features", w / "b13.png", "--band", "0.8", "0.2"),
        "features --max-pixels 0": ("features", w / "b13.png", "--max-pixels", "0"),
        "features on a missing image": ("features", w / "missing.png"),
        "features on a text file named .png": ("features", w / "text.png"),
        "demo --workers 0": ("demo", "--quick", "--workers", "0"),
        "fingerprint --merge-tol-deg -1": ("fingerprint", train, "--merge-tol-deg", "-1"),
    }.items():
        b.expect_error(name, *args, db=db)
    b.expect_ok("fingerprint --json of a labelled file", "fingerprint", train, "--json",
                check=lambda r: "" if all(json.loads(x)["place"] for x in r.out.splitlines()) else "bad JSON")  # fmt: skip

    # -- database mechanics
    real = w / "store" / "real.sqlite"
    real.parent.mkdir()
    link = w / "link.sqlite"
    link.symlink_to(real)
    b.expect_ok("learn into a symlink keeps the link", "learn", train, "--db", link,
                check=lambda r: "" if link.is_symlink() and real.is_file() else "the link was replaced")  # fmt: skip
    udb = w / "u.sqlite"
    b.expect_ok("new database mode follows the umask (022 -> 0644)", "learn", train, "--db", udb,
                check=lambda r: "" if (udb.stat().st_mode & 0o777) == 0o644 else oct(udb.stat().st_mode & 0o777))  # fmt: skip
    stale = w / "u.sqlite.dead12.tmp"
    stale.write_bytes(b"x")
    b.expect_ok("stale temporary file removed", "learn", _places_file(w / "d.jsonl", ["d"]), "--db", udb,
                check=lambda r: "" if not stale.exists() else "stale file left")  # fmt: skip
    _concurrent(b, w)
    _hot_journal(b, w, db)


def _concurrent(b: Battery, w: Path) -> None:
    cdb = w / "conc.sqlite"
    files = [_places_file(w / f"w{k}.jsonl", [f"w{k}-{i}" for i in range(20)], offset=25 * k) for k in range(2)]
    env = {**os.environ, "PYTHONPATH": str(b.src)}
    cmd = [sys.executable, "-c", "from fingerloc.cli import main; main()", "learn"]
    procs = [
        subprocess.Popen([*cmd, str(f), "--db", str(cdb)], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        for f in files
    ]
    codes = [p.wait(timeout=300) for p in procs]
    r = b.run("places", "--db", cdb, "--json")
    try:
        n = len(json.loads(r.out)["places"])
    except (ValueError, KeyError):
        n = -1
    b.record("two concurrent learns keep every place", codes == [0, 0] and n == 40, f"exit {codes}, {n} places")


def _hot_journal(b: Battery, w: Path, db: Path) -> None:
    hdb = w / "hot.sqlite"
    shutil.copyfile(db, hdb)
    code = (
        "import sqlite3, os\n"
        f"con = sqlite3.connect({str(hdb)!r}, isolation_level=None)\n"
        "con.execute('PRAGMA cache_size=1')\n"
        "con.execute('BEGIN')\n"
        "con.execute(\"UPDATE places SET label = label || '-x'\")\n"
        "con.execute('CREATE TABLE junk(x)')\n"
        "con.executemany('INSERT INTO junk VALUES (?)', [(b'0' * 4000,)] * 200)\n"
        "os._exit(0)\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)
    if Path(str(hdb) + "-journal").exists():
        b.expect_ok("a hot journal is rolled back by SQLite", "places", "--db", hdb)


if __name__ == "__main__":
    raise SystemExit(main())
