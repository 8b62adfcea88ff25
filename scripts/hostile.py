#!/usr/bin/env python3
"""Fault and hostile-input batteries for the ``fingerloc`` command line (docs/ROBUSTNESS.md); not part of CI.

Each case runs the real entry point in a subprocess (address space bounded
by ``HOSTILE_MEMORY_LIMIT``, a time limit per case). A case meant to fail is
clean when the command exits with 2, prints exactly one ``error: ...`` line
and leaves the files it names as they were (a FIFO a FIFO, a link a link); a
case meant to succeed, when it exits with 0 and its check holds.

* ``inputs``: usage errors, hostile JSON Lines, output paths, crafted
  databases, images, option ranges, failed commands that change nothing,
  files that are not sensor files, strict JSON, database mechanics;
* ``faults``: data loss (learn into a map, track with a concurrent learn, a
  WAL file, devices, FIFOs, link loops), what does not fit, loaded values,
  faults (file-size limit, full device, closed pipe, long names), bounded
  readers, images read as meant, bags, and the streaming surfaces (``track
  -`` / ``--follow``, ``--tum`` / ``--kitti``, ``map --places fingerprints``,
  ``features --labels``, ``bench loops`` / ``bench live``).

Usage: ``python scripts/hostile.py [-v] [--battery inputs|faults|all] [-k TEXT]... [--src OTHER/src]``.
Prints ``clean N of M`` per battery and in all, the commands stopped at their
time limit and the largest resident set; exits 0 when every case is clean.
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
import threading
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hostile_files import carmen_log, places_file, png, real_png, shifted_log, stripes16, write_bag

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
    def __init__(self, src: Path, work: Path, verbose: bool, only: list[str] | None = None) -> None:
        self.src = src
        self.work = work
        self.verbose = verbose
        self.only = only or []
        self.results: list[tuple[str, bool, str]] = []
        self.hangs = 0  # commands stopped at their time limit
        self.peak: tuple[int, str] = (0, "")  # largest resident set of a command (KiB) and the first case reaching it

    def run(
        self,
        *args: object,
        timeout: float = 180.0,
        env: dict[str, str] | None = None,
        stdout: Any = subprocess.PIPE,
        fsize: int | None = None,
        stdin: Path | str | None = None,
    ) -> Result:
        """``stdin``: a file to read as standard input, ``"closed"`` (``<&-``), or ``None`` (no input)."""
        e = {**os.environ, "PYTHONPATH": str(self.src), **(env or {})}
        cmd = [sys.executable, "-c", "from fingerloc.cli import main; main()", *map(str, args)]

        def limits() -> None:
            _limit_memory()
            if stdin == "closed":
                os.close(0)
            if fsize is not None:
                import resource

                resource.setrlimit(resource.RLIMIT_FSIZE, (fsize, fsize))

        src = subprocess.DEVNULL if stdin in (None, "closed") else open(stdin, "rb")
        try:
            p = subprocess.run(cmd, stdin=src, stdout=stdout, stderr=subprocess.PIPE, timeout=timeout, cwd=self.work,
                               env=e, preexec_fn=limits)  # fmt: skip
        except subprocess.TimeoutExpired:
            self.hangs += 1
            return Result(-9, "", "timeout")
        finally:
            if src is not subprocess.DEVNULL:
                src.close()
        out = p.stdout.decode("utf-8", "replace") if isinstance(p.stdout, bytes) else ""
        return Result(p.returncode, out, p.stderr.decode("utf-8", "replace"))

    def wanted(self, name: str) -> bool:
        return not self.only or any(k.lower() in name.lower() for k in self.only) or "(setup" in name

    def record(self, name: str, ok: bool, why: str = "") -> None:
        import resource

        self.results.append((name, ok, why))
        rss = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
        if rss > self.peak[0]:
            self.peak = (rss, name)
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
        setup = "(setup" in name
        if setup:  # the first commands compile the kernels (numba's cache): a loaded machine takes minutes
            run.setdefault("timeout", 1200.0)
        r = self.run(*args, **run)
        why = "" if r.code == 0 else f"exit {r.code}: {r.err.strip()[-200:]!r}"
        if not why and check is not None:
            why = check(r)
        self.record(name, not why, why)
        if why and setup:
            raise SystemExit(f"setup failed, the battery cannot go on: {name}: {why}")
        return r

    def expect_warning(self, name: str, *args: object, needle: str, **run: Any) -> Result:
        """An answer with a doubt: exit 0 and a ``warning:`` line holding ``needle``."""
        def check(r: Result) -> str:
            ok = any(x.startswith("warning: ") and needle.lower() in x.lower() for x in r.err.splitlines())
            return "" if ok else f"no warning with {needle!r}: {r.err.strip()[-200:]!r}"

        return self.expect_ok(name, *args, check=check, **run)


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
    ap.add_argument("-k", dest="only", action="append", default=[],
                    help="only the cases whose name holds this text (repeatable: any of them)")  # fmt: skip
    ap.add_argument("--battery", choices=("inputs", "faults", "all"), default="all",
                    help="inputs: bad input files, options and databases; faults: data loss, faults, readers, "
                    "streams and the other categories above; all: both")  # fmt: skip
    args = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="fingerloc-hostile-"))
    parts: list[tuple[str, int, int]] = []
    b = Battery(args.src.resolve(), work, args.verbose, args.only)
    try:
        for label, battery in (("inputs", inputs_battery), ("faults", faults_battery)):
            if args.battery in (label, "all"):
                start = len(b.results)
                battery(b, work)
                parts.append((label, start, len(b.results)))
    finally:
        shutil.rmtree(work, ignore_errors=True)
    for label, start, end in parts:
        part = b.results[start:end]
        print(f"{label} battery: clean {sum(ok for _, ok, _ in part)} of {len(part)}")
    clean = sum(ok for _, ok, _ in b.results)
    print(f"clean {clean} of {len(b.results)}; commands stopped at their time limit: {b.hangs}; "
          f"largest resident set: {b.peak[0] / 1024:.0f} MiB ({b.peak[1]})")  # fmt: skip
    return 0 if clean == len(b.results) else 1


def inputs_battery(b: Battery, w: Path) -> None:
    train = places_file(w / "train.jsonl", ["a", "b", "c"])
    db = w / "p.sqlite"
    # the paper's program: every table of the database has rows to craft
    b.expect_ok("learn (setup)", "learn", train, "--db", db, "--preset", "paper")
    log = carmen_log(w / "rooms.log")

    # -- usage errors
    b.expect_error("unknown option", "learn", "--bogus")
    b.expect_error("missing argument", "learn")
    b.expect_error("option not an integer", "localize", train, "--db", db, "--top", "many")
    b.expect_error("unknown command", "nosuchcommand")
    b.expect_error("non-UTF-8 argument", "fingerprint", "bad\udcff.jsonl")

    # -- markup and surrogates in user strings
    for label in ("[/x]", "[red]b[/red]"):
        data = places_file(w / "m.jsonl", [label, "plain"])
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
    b.expect_error("track LOG --filter pose --db learned from JSON Lines", "track", log, "--db", db, "--filter", "pose",
                   db=db)  # fmt: skip

    # -- images, option ranges
    b.expect_error("20000x20000 PNG", "features", png(w / "b20.png", 20000, 20000))
    b.expect_error("13000x13000 PNG", "features", png(w / "b13.png", 13000, 13000))
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
    one = places_file(w / "one.jsonl", ["a"])
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
    one_scan = carmen_log(w / "one-scan.log", scans=1)
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
    b.expect_ok("stale temporary file removed", "learn", places_file(w / "d.jsonl", ["d"]), "--db", udb,
                check=lambda r: "" if not stale.exists() else "stale file left")  # fmt: skip
    _concurrent(b, w)
    _hot_journal(b, w, db)


def _concurrent(b: Battery, w: Path) -> None:
    cdb = w / "conc.sqlite"
    files = [places_file(w / f"w{k}.jsonl", [f"w{k}-{i}" for i in range(20)], offset=25 * k) for k in range(2)]
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


# == the faults battery ==========================================================================


def faults_battery(b: Battery, w: Path) -> None:
    d = w / "faults"
    d.mkdir()
    log = carmen_log(d / "rooms.log")
    laser = d / "laser.sqlite"
    b.expect_ok("map (setup)", "map", log, "--db", laser, "--no-calibration", "--no-heading", "--json",
                d / "lt.jsonl", "--queries", d / "lq.jsonl")  # fmt: skip
    train = places_file(d / "train.jsonl", ["a", "b", "c"])
    learned = d / "learned.sqlite"
    b.expect_ok("learn (setup)", "learn", train, "--db", learned, "--preset", "paper")
    image = d / "image.sqlite"
    pano = d / "pano.jsonl"
    pano.write_text("\n".join(json.dumps({"place": p, "features": {"CP": [
        {"bearing": (40 * j + 13 * k) % 360, "hue": 30 * j} for j in range(4)]}})
        for k, p in enumerate(["a", "a", "b", "b", "c", "c"])) + "\n")  # fmt: skip
    b.expect_ok("learn images (setup)", "learn", pano, "--db", image, "--no-calibration")
    _data_loss(b, d, log, laser, train)
    _fit(b, d, log, laser, image, pano, train)
    _loaded(b, d, learned, laser, train)
    _faults(b, d, learned, train)
    _readers(b, d, learned, laser, train)
    _images(b, d)
    _bags(b, d)
    _surfaces(b, d, log, laser)


def _records(path: Path) -> list[dict[str, Any]]:
    try:
        return [json.loads(x) for x in path.read_text().splitlines() if x.strip()]
    except (OSError, ValueError):
        return []


def _copy(src: Path, dst: Path) -> Path:
    shutil.copyfile(src, dst)
    return dst


def _places_json(b: Battery, db: Path) -> dict[str, Any]:
    r = b.run("places", "--db", db, "--json")
    try:
        return json.loads(r.out)
    except ValueError:
        return {}


# -- data loss: the writer protocol ------------------------------------------------------------------


def _data_loss(b: Battery, d: Path, log: Path, laser: Path, train: Path) -> None:
    # learn into a map: positions kept, a new place placed at its views' poses
    m = _copy(laser, d / "m1.sqlite")
    n_before = len(_places_json(b, m).get("positions", {}))
    views = [json.loads(x) for x in (d / "lq.jsonl").read_text().splitlines()]
    for v in views[:2]:
        v["place"] = "new"
        v["pose"] = [v["pose"][0] + 3.0, v["pose"][1], v["pose"][2]]
    extra = d / "extra.jsonl"
    extra.write_text("\n".join(json.dumps(v) for v in views[:2]) + "\n")
    b.expect_ok("learn into a map keeps its place positions", "learn", extra, "--db", m,
                check=lambda r: "" if len(_places_json(b, m).get("positions", {})) == n_before + 1 > 1
                else f"positions {n_before} -> {len(_places_json(b, m).get('positions', {}))}")  # fmt: skip
    b.expect_error("learn a place without a pose into a map", "learn", places_file(d / "np.jsonl", ["far"], poses=False), "--db",
                   _copy(laser, d / "m2.sqlite"), needle="pose", db=d / "m2.sqlite")  # fmt: skip
    # track --graph-from with a concurrent learn: every place stays
    c = d / "conc.sqlite"
    b.expect_ok("learn (setup of the concurrent writers)", "learn", train, "--db", c, "--no-calibration")
    more = places_file(d / "more.jsonl", [f"x{i}" for i in range(8)], offset=7)
    env = {**os.environ, "PYTHONPATH": str(b.src)}
    cmd = [sys.executable, "-c", "from fingerloc.cli import main; main()"]
    track = subprocess.Popen([*cmd, "track", str(train), "--db", str(c), "--graph-from", str(train), "-q"], env=env,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE)  # fmt: skip
    learn = subprocess.Popen([*cmd, "learn", str(more), "--db", str(c)], env=env, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE)  # fmt: skip
    codes = [track.wait(timeout=600), learn.wait(timeout=600)]
    n = len(_places_json(b, c).get("places", []))
    b.record("track --graph-from and a concurrent learn keep every place", codes == [0, 0] and n == 11,
             f"exit {codes}, {n} of 11 places")  # fmt: skip
    # a WAL file left by another program
    wal = _copy(d / "conc.sqlite", d / "wal.sqlite")
    code = ("import sqlite3, os, sys\ncon = sqlite3.connect(sys.argv[1], isolation_level=None)\n"
            "con.execute('PRAGMA journal_mode=WAL')\n"
            "con.execute(\"UPDATE meta SET value = value WHERE key = 'format'\")\nos._exit(0)\n")  # fmt: skip
    subprocess.run([sys.executable, "-c", code, str(wal)], check=True)
    b.expect_ok("learn into a database with a WAL file of another program", "learn",
                places_file(d / "w.jsonl", ["w"], offset=30), "--db", wal,
                check=lambda r: "" if not Path(f"{wal}-wal").exists() and b.run("places", "--db", wal).code == 0
                else "WAL left or the database does not open")  # fmt: skip
    # outputs that are not regular files
    fifo = d / "out.fifo"
    os.mkfifo(fifo)
    b.expect_error("localize --json into a FIFO", "localize", train, "--db", learned_or(d), "--json", fifo,
                   needle="FIFO", keep=(fifo,))  # fmt: skip
    b.expect_error("map --db a FIFO --overwrite", "map", log, "--db", fifo, "--overwrite", needle="FIFO", keep=(fifo,))
    dev = d / "null-like"
    try:
        os.mknod(dev, 0o20666, os.makedev(1, 3))
        b.expect_error("learn --db a character device", "learn", train, "--db", dev, needle="character device",
                       keep=(dev,))  # fmt: skip
        b.expect_error("localize --json a character device", "localize", train, "--db", learned_or(d), "--json",
                       dev, needle="character device", keep=(dev,))  # fmt: skip
    except OSError:
        pass
    loop = d / "loop.sqlite"
    loop.symlink_to(loop.name)
    b.expect_error("learn --db a symbolic link loop", "learn", train, "--db", loop, needle="loop", keep=(loop,))


def learned_or(d: Path) -> Path:
    return d / "learned.sqlite"


# -- what does not fit ---------------------------------------------------------------------------------


def _fit(b: Battery, d: Path, log: Path, laser: Path, image: Path, pano: Path, train: Path) -> None:
    b.expect_error("localize image observations against a laser map", "localize", pano, "--db", laser, "-q",
                   needle="laser")  # fmt: skip
    b.expect_error("localize a laser log against an image database", "localize", log, "--db", image, "-q",
                   needle="image")  # fmt: skip
    b.expect_error("track a laser log against an image database", "track", d / "lq.jsonl", "--db", image, "-q",
                   needle="image", db=image)  # fmt: skip
    b.expect_error("learn laser views into an image database", "learn", d / "lt.jsonl", "--db", image,
                   needle="image", db=image)  # fmt: skip
    far = shifted_log(log, d / "far.log", 5000.0)
    b.expect_error("localize a run in another frame", "localize", far, "--db", laser, "-q", needle="frame")
    b.expect_error("track a run in another frame", "track", far, "--db", laser, "-q", needle="frame", db=laser)
    still = d / "still.log"
    lines = [x for x in log.read_text().splitlines() if not x.startswith(("FLASER", "ODOM"))]
    flaser = next(x for x in log.read_text().splitlines() if x.startswith("FLASER"))
    still.write_text("\n".join(lines + [flaser] * 12) + "\n")
    b.expect_warning("map a stationary run", "map", still, "--db", d / "still.sqlite", "--no-calibration",
                     needle="moves")  # fmt: skip
    b.expect_warning("localize fewer than ten queries", "localize", train, "--db", d / "learned.sqlite", "-q",
                     needle="rough")  # fmt: skip
    b.expect_error("map -k 1e20", "map", log, "--db", d / "k.sqlite", "-k", "100000000000000000000")
    b.expect_error("map -k 5000", "map", log, "--db", d / "k.sqlite", "-k", "5000", needle="components")
    empty = d / "empty-views.jsonl"
    empty.write_text("\n".join(json.dumps({"place": p, "features": {}, "pose": [k, 0, 0]})
                               for k, p in enumerate("aabbcc")) + "\n")  # fmt: skip
    b.expect_error("localize observations that all have no feature", "localize", empty, "--db", laser, "-q",
                   needle="feature")  # fmt: skip


# -- loaded values checked ----------------------------------------------------------------------------


def _crafted(src: Path, dst: Path, sql: str, *params: Any) -> Path:
    shutil.copyfile(src, dst)
    with sqlite3.connect(dst) as con:
        con.execute(sql, params)
    con.close()
    return dst


RADIUS_INF = (
    "UPDATE meta SET value = replace(value, '\"radius\":1.0', '\"radius\":Infinity') WHERE key = 'calibration'"
)
RUNS_BAD = "UPDATE meta SET value = '[{\"name\": \"x\", \"n_scans\": 1, \"n_mapping\": 5}]' WHERE key = 'runs'"


def _loaded(b: Battery, d: Path, learned: Path, laser: Path, train: Path) -> None:
    cal = json.dumps({"beta": float("nan"), "radius": 1.0})
    crafted = {
        "beta NaN": (laser, "UPDATE meta SET value = ? WHERE key = 'calibration'", cal),
        "radius inf": (laser, RADIUS_INF),
        "calibration as a list": (laser, "UPDATE meta SET value = '[1, 2]' WHERE key = 'calibration'"),
        "lambda -5": (learned, "UPDATE meta SET value = '{\"Fp\": -5}' WHERE key = 'lambdas'"),
        "a position of 1e300": (laser, "UPDATE place_positions SET x = 1e300 WHERE idx = 0"),
        "a position as text": (laser, "UPDATE place_positions SET x = 'here' WHERE idx = 0"),
        "no range_descriptors table": (laser, "DROP TABLE range_descriptors"),
        "5-byte content hashes": (laser, "UPDATE content_hashes SET hash = X'0102030405' WHERE hash = "
                                  "(SELECT hash FROM content_hashes LIMIT 1)"),
        "mixture weights summing to 3": (learned, "UPDATE mixtures SET weights = ? WHERE rowid = 1",),
        "a flipped byte in a record": (laser, "UPDATE observations SET data = ? WHERE id = 1"),
        "a run with more mapping scans than scans": (laser, RUNS_BAD),
    }
    for name, (src, sql, *params) in crafted.items():
        dst = d / "crafted.sqlite"
        if name == "mixture weights summing to 3":
            with sqlite3.connect(src) as con:
                (wts,) = con.execute("SELECT weights FROM mixtures WHERE rowid = 1").fetchone()
            con.close()
            params = [struct.pack(f"<{len(wts) // 8}d", *(3 * v for v in struct.unpack(f"<{len(wts) // 8}d", wts)))]
        if name == "a flipped byte in a record":
            with sqlite3.connect(src) as con:
                (data,) = con.execute("SELECT data FROM observations WHERE id = 1").fetchone()
            con.close()
            k = len(data) - 3
            params = [data[:k] + bytes([data[k] ^ 0x10]) + data[k + 1 :]]
        try:
            _crafted(src, dst, sql, *params)
        except sqlite3.Error as err:
            b.record(f"crafted database: {name}", False, f"crafting failed: {err}")
            continue
        cmd = ("track", d / "lq.jsonl", "--db", dst, "-q") if src == laser else ("localize", train, "--db", dst, "-q")
        b.expect_error(f"crafted database: {name}", *cmd, db=dst)


# -- faults ---------------------------------------------------------------------------------------------


def _faults(b: Battery, d: Path, learned: Path, train: Path) -> None:
    db = _copy(learned, d / "f.sqlite")
    more = places_file(d / "fmore.jsonl", [f"f{i}" for i in range(40)], offset=3)
    b.expect_error("learn under a file-size limit (ulimit -f)", "learn", more, "--db", db, fsize=db.stat().st_size // 2,
                   db=db)  # fmt: skip
    out = d / "f.json"
    out.write_text("old\n")
    b.expect_error("localize --json under a file-size limit", "localize", train, "--db", learned, "--json", out, "-q",
                   fsize=300, keep=(out,))  # fmt: skip
    if Path("/dev/full").exists():
        with open("/dev/full", "wb") as full:
            b.expect_error("places with stdout on a full device", "places", "--db", learned, stdout=full,
                           needle="no space")  # fmt: skip
    if b.wanted("a closed pipe"):
        many = places_file(d / "many.jsonl", [f"p{i}" for i in range(2000)])
        env = {**os.environ, "PYTHONPATH": str(b.src)}
        proc = subprocess.Popen([sys.executable, "-c", "from fingerloc.cli import main; main()", "fingerprint",
                                 str(many), "--json"], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)  # fmt: skip
        assert proc.stdout is not None and proc.stderr is not None
        proc.stdout.read(10)
        proc.stdout.close()
        err = proc.stderr.read().decode()
        code = proc.wait(timeout=300)
        lines = err.strip().splitlines()
        b.record("fingerprint into a closed pipe", code == 2 and len(lines) == 1 and lines[0].startswith("error: "),
                 f"exit {code}: {err.strip()[-160:]!r}")  # fmt: skip
    b.expect_ok("localize --json into a 248-character name", "localize", train, "--db", learned, "--json",
                d / ("n" * 243 + ".json"), "-q")  # fmt: skip
    b.expect_error("localize --json into a 300-character name", "localize", train, "--db", learned, "--json",
                   d / ("n" * 300 + ".json"), "-q", needle="too long")  # fmt: skip
    b.expect_error("learn --lock-timeout nan", "learn", train, "--db", d / "lt.sqlite", "--lock-timeout", "nan")


# -- bounded readers -------------------------------------------------------------------------------------


def _readers(b: Battery, d: Path, learned: Path, laser: Path, train: Path) -> None:
    if b.wanted("a CARMEN log through a FIFO"):
        fifo = d / "log.fifo"
        os.mkfifo(fifo)
        src = (d / "rooms.log").read_bytes()

        def feed() -> None:
            try:
                with open(fifo, "wb") as fh:
                    fh.write(src)
            except OSError:
                pass

        t = threading.Thread(target=feed, daemon=True)
        t.start()
        b.expect_ok("localize a CARMEN log through a FIFO", "localize", fifo, "--kind", "carmen", "--db", laser, "-q",
                    timeout=120)  # fmt: skip
        if t.is_alive():  # the reader never opened it: unblock the writer
            with open(fifo, "rb") as fh:
                fh.read()
    nul = d / "nul.log"
    with open(nul, "wb") as fh:
        fh.truncate(2 << 30)  # 2 GB of NUL bytes, sparse
    b.expect_error("localize a 2 GB file of NUL bytes", "localize", nul, "--db", laser, "-q", timeout=60)
    b.expect_error("localize /dev/zero as a CARMEN log", "localize", "/dev/zero", "--kind", "carmen", "--db", laser,
                   "-q", timeout=60)  # fmt: skip
    b.expect_error("localize /dev/zero as JSON Lines", "localize", "/dev/zero", "--kind", "jsonl", "--db", learned,
                   "-q", timeout=60)  # fmt: skip
    giant = d / "giant.log"
    with open(giant, "wb") as fh:
        fh.write(b"FLASER 3 ")
        for _ in range(200):
            fh.write(b"1.0 " * 65536)
    b.expect_error("features on a 50 MB line", "features", giant, timeout=60)
    blank = d / "blank.log.gz"
    with gzip.open(blank, "wb", compresslevel=9) as gz:
        chunk = b"\n" * (1 << 24)
        for _ in range(64):  # 1 GiB of blank lines, 1 MB compressed
            gz.write(chunk)
    b.expect_error("localize a gzip of 1 GiB of blank lines", "localize", blank, "--db", laser, "-q", timeout=120)
    if b.wanted("a held writer lock"):
        held = _copy(learned, d / "held.sqlite")
        import fcntl

        fd = os.open(f"{held}.lock", os.O_RDWR | os.O_CREAT)
        fcntl.flock(fd, fcntl.LOCK_EX)
        try:
            b.expect_error("learn into a database whose writer lock is held (a held writer lock)", "learn", train,
                           "--db", held, "--lock-timeout", "1", notes=1, needle="lock", db=held, timeout=120)  # fmt: skip
        finally:
            os.close(fd)
    b.expect_error("features on a 64x20000 PNG", "features", real_png(d / "tall.png", 64, 20000), timeout=120)


# -- images read as they are meant ----------------------------------------------------------------------


def _images(b: Battery, d: Path) -> None:
    g16 = real_png(d / "g16.png", 1440, 360, depth=16, rows=stripes16)
    out = d / "g16.jsonl"

    def edges(r: Result) -> str:
        n = [len(rec.get("features", {}).get("VE", [])) for rec in _records(out)]
        return "" if n and min(n) > 0 else f"no vertical edge found ({n})"

    b.expect_ok("features of a 16-bit PNG (scaled, not clipped)", "features", g16, "--json", out, check=edges)
    try:
        import numpy as np
        from PIL import Image
    except ImportError:
        return
    rng = np.random.default_rng(0)
    img = np.kron((rng.random((9, 36)) * 255).astype(np.uint8), np.ones((40, 40), dtype=np.uint8))
    rgb = np.repeat(img[:, :, None], 3, axis=2)
    Image.fromarray(rgb).save(d / "up.jpg", quality=95)
    rot = Image.fromarray(np.ascontiguousarray(np.rot90(rgb, 1)))  # stored turned, the tag says how to turn back
    exif = rot.getexif()
    exif[0x0112] = 6
    rot.save(d / "turned.jpg", quality=95, exif=exif.tobytes())
    b.run("features", d / "up.jpg", "--json", d / "up.jsonl")

    def same(r: Result) -> str:
        a = [rec.get("features") for rec in _records(d / "up.jsonl")]
        c = [rec.get("features") for rec in _records(d / "turned.jsonl")]
        return "" if a and a == c else "features differ from the upright file's"

    b.expect_ok("features of a JPEG with an EXIF orientation", "features", d / "turned.jpg", "--json",
                d / "turned.jsonl", check=same)  # fmt: skip
    full = (d / "up.jpg").read_bytes()
    (d / "cut.jpg").write_bytes(full[: len(full) // 2] + b"\xff\xd9")
    b.expect_error("features of a JPEG cut before its end", "features", d / "cut.jpg", needle="truncated")
    raw = b"".join(b"\0" + bytes(rgb[y].reshape(-1)) for y in range(rgb.shape[0] // 2))

    def chunk(t: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + t + data + struct.pack(">I", zlib.crc32(t + data) & 0xFFFFFFFF)

    ihdr = struct.pack(">IIBBBBB", rgb.shape[1], rgb.shape[0], 8, 2, 0, 0, 0)
    (d / "short.png").write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(raw))
                                  + chunk(b"IEND", b""))  # fmt: skip
    b.expect_error("features of a PNG with half its rows", "features", d / "short.png", needle="truncated")
    b.expect_error("features --bearing-offset-deg inf", "features", d / "up.jpg", "--bearing-offset-deg", "inf")
    b.expect_error("features --bearing-offset-deg nan", "features", d / "up.jpg", "--bearing-offset-deg", "nan")


# -- bags -------------------------------------------------------------------------------------------------


def _bags(b: Battery, d: Path) -> None:
    try:
        import rosbags  # noqa: F401
    except ImportError:
        return
    nan_bag = write_bag(d / "nan-bag", ranges=float("nan"), stamps=8)
    b.expect_error("map a bag whose ranges are all NaN", "map", nan_bag, "--db", d / "nan.sqlite", "--pose-source",
                   "odom", "--no-calibration", needle="return")  # fmt: skip
    far_bag = write_bag(d / "far-bag", ranges=100.0, stamps=8)
    b.expect_error("map a bag whose ranges are all beyond range_max", "map", far_bag, "--db", d / "far.sqlite",
                   "--pose-source", "odom", "--no-calibration", needle="return")  # fmt: skip
    inf_bag = write_bag(d / "inf-bag", mount=(math.inf, math.nan, 0.0))
    b.expect_error("features of a bag with a lidar mount at (inf, nan)", "features", inf_bag, needle="translation")
    good = write_bag(d / "good-bag")
    dmg = d / "damaged-bag"
    shutil.copytree(good, dmg)
    db3 = next(dmg.glob("*.db3"), None) or next(dmg.glob("*.mcap"), None)
    if db3 is not None:
        raw = bytearray(db3.read_bytes())
        for k in range(len(raw) // 3, len(raw) // 3 + 4096, 7):
            raw[k] ^= 0x5A
        db3.write_bytes(bytes(raw))
        b.expect_error("features of a bag with damaged messages", "features", dmg)
    two = write_bag(d / "two-lidars", topics=("/scan_front", "/scan_back"), beacon=True, scales=(1000.0, 40.0))

    out = d / "two.jsonl"

    def beacon(r: Result) -> str:
        n = [len(rec.get("features", {}).get("B", [])) for rec in _records(out)]
        return "" if n and min(n) > 0 else f"no beacon in the merged scans ({n})"

    b.expect_ok("features of two merged lidars keep the back lidar's beacon", "features", two, "--topic",
                "/scan_front", "--topic", "/scan_back", "--pose-source", "none", "--json", out, check=beacon)  # fmt: skip


# -- streams, trajectories, maps from fingerprints, labels CSV, loop and live benchmarks ------------------


def _feed_fifo(fifo: Path, data: bytes) -> threading.Thread:
    def feed() -> None:
        try:
            with open(fifo, "wb") as fh:
                fh.write(data)
        except OSError:
            pass

    t = threading.Thread(target=feed, daemon=True)
    t.start()
    return t


def _surfaces(b: Battery, d: Path, log: Path, laser: Path) -> None:
    s = d / "surfaces"
    s.mkdir()
    text = log.read_text().splitlines()
    bad = s / "bad.log"
    bad.write_text("\n".join([*text[:2], "FLASER many 1 2", *text[2:]]) + "\n")
    b.expect_error("track - with a bad line", "track", "-", "--db", laser, "-q", stdin=bad, needle="beam count")
    b.expect_warning("track - --skip-bad with a bad line", "track", "-", "--db", laser, "-q", "--skip-bad", stdin=bad,
                     needle="beam count")  # fmt: skip
    b.expect_error("track - with standard input closed", "track", "-", "--db", laser, stdin="closed", needle="closed")
    b.expect_error("track - on /dev/zero", "track", "-", "--db", laser, stdin="/dev/zero", needle="longer", timeout=60)
    b.expect_error("track --follow /dev/zero", "track", "/dev/zero", "--follow", "--db", laser, needle="longer",
                   timeout=60)  # fmt: skip
    fifo = s / "in.fifo"
    os.mkfifo(fifo)
    if b.wanted("track --follow on a FIFO"):
        t = _feed_fifo(fifo, log.read_bytes())
        b.expect_ok("track --follow on a FIFO ends with its writer", "track", fifo, "--follow", "--kind", "carmen",
                    "--db", laser, "-q", timeout=120)  # fmt: skip
        if t.is_alive():  # the reader never opened it: unblock the writer
            with open(fifo, "rb") as fh:
                fh.read()
    old = s / "old.json"
    old.write_text("old\n")
    (s / "adir").mkdir()
    for name, target in (("a directory", s / "adir"), ("a FIFO", fifo), ("/dev/full", Path("/dev/full"))):
        for flag in ("--tum", "--kitti"):
            b.expect_error(f"track {flag} into {name}", "track", log, "--db", laser, "--filter", "pose", "-q", "--json",
                           old, flag, target, needle=flag, keep=(old, fifo))  # fmt: skip
        b.expect_error(f"track - --tum into {name}", "track", "-", "--db", laser, "--json", old, "--tum", target,
                       stdin=log, needle="--tum", keep=(old, fifo))  # fmt: skip
        b.expect_error(f"map --tum into {name}", "map", log, "--db", s / "new.sqlite", "--tum", target,
                       needle="--tum", keep=(s / "new.sqlite", fifo))  # fmt: skip
    tum = s / "t.tum"
    tum.write_text("old tum\n")
    b.expect_error("track --json --tum under a file-size limit keeps both", "track", log, "--db", laser, "--filter",
                   "pose", "-q", "--json", old, "--tum", tum, fsize=2000, keep=(old, tum, laser), notes=2)  # fmt: skip
    if os.geteuid() != 0:
        ro = s / "ro"
        ro.mkdir()
        ro.chmod(0o500)
        b.expect_error("track --kitti into a read-only directory", "track", log, "--db", laser, "--filter", "pose",
                       "--json", old, "--kitti", ro / "t.kitti", keep=(old,))  # fmt: skip
    b.record("no temporary file left by the trajectory cases", not list(s.glob("**/*.tmp")), "a .tmp file left")
    # maps from fingerprints on runs that cannot make one
    b.expect_error("map --places fingerprints on one scan", "map", carmen_log(s / "one.log", scans=1), "--db",
                   s / "one.sqlite", "--places", "fingerprints", keep=(s / "one.sqlite",))  # fmt: skip
    nan = s / "nan.log"
    nan.write_text("\n".join(x if not x.startswith("FLASER") else " ".join(
        ["FLASER", "181", *["nan"] * 181, *x.split()[183:]]) for x in text) + "\n")  # fmt: skip
    b.expect_error("map --places fingerprints on all-NaN ranges", "map", nan, "--db", s / "nan.sqlite", "--places",
                   "fingerprints", needle="return", keep=(s / "nan.sqlite",))  # fmt: skip
    flaser = next(x for x in text if x.startswith("FLASER"))
    (s / "still.log").write_text("\n".join([*text[:2], *[flaser] * 12]) + "\n")
    b.expect_warning("map --places fingerprints on a stationary run", "map", s / "still.log", "--db",
                     s / "still.sqlite", "--places", "fingerprints", needle="stationary")  # fmt: skip
    # features --labels with a bad CSV
    photo = real_png(s / "p1.png", 720, 180, rows=lambda y: bytes(255 * ((x // 36) % 2) for x in range(720)))
    shutil.copyfile(photo, s / "p2.png")
    csvs = {
        "missing columns": (b"name,room\np1.png,a\np2.png,b\n", "columns"),
        "an unknown photo": (b"file,place\np1.png,a\n", "no row"),
        "duplicate rows": (b"file,place\np1.png,a\np1.png,b\np2.png,b\n", "twice"),
        "non-UTF-8": (b"file,place\np1.png,caf\xe9\np2.png,b\n", "UTF-8"),
        "NUL bytes": (b"file,place\np1.png,a\x00\np2.png,b\n", "NUL"),
        "a 200 kB field": (b"file,place\np1.png," + b"x" * 200_000 + b"\np2.png,b\n", "CSV"),
    }
    out = s / "labelled.jsonl"
    for name, (content, needle) in csvs.items():
        (s / "labels.csv").write_bytes(content)
        b.expect_error(f"features --labels with {name}", "features", s / "p1.png", s / "p2.png", "--labels",
                       s / "labels.csv", "--json", out, needle=needle, keep=(out,))  # fmt: skip
    b.expect_error("features --labels /dev/zero", "features", s / "p1.png", "--labels", "/dev/zero", timeout=60)
    (s / "bom.csv").write_bytes(b"\xef\xbb\xbffile,place\r\np1.png,a\r\np2.png,b\r\n")
    b.expect_ok("features --labels with a BOM", "features", s / "p1.png", s / "p2.png", "--labels", s / "bom.csv",
                "--json", out, check=lambda r: "" if [x.get("place") for x in _records(out)] == ["a", "b"]
                else f"places {[x.get('place') for x in _records(out)]}")  # fmt: skip
    # bench loops / bench live with bad arguments
    train = places_file(s / "train.jsonl", ["a", "b"])
    for name, args in {
        "bench loops --distance nan": ("bench", "loops", log, "--distance", "nan"),
        "bench loops --exclude-s -1": ("bench", "loops", log, "--exclude-s", "-1"),
        "bench loops -m nope": ("bench", "loops", log, "-m", "nope"),
        "bench loops on JSON Lines": ("bench", "loops", train),
        "bench loops on a missing log": ("bench", "loops", s / "missing.log"),
        "bench loops --json into a FIFO": ("bench", "loops", log, "--json", fifo),
        "bench live --only nope": ("bench", "live", log, "--only", "nope"),
        "bench live --places 0": ("bench", "live", log, "--places", "0"),
        "bench live on JSON Lines": ("bench", "live", train, "--only", "latency"),
        "bench live --latency-log a directory": ("bench", "live", log, "--latency-log", s / "adir"),
        "bench live --json into a FIFO": ("bench", "live", log, "--json", fifo),
    }.items():
        b.expect_error(name, *args, keep=(fifo,), timeout=300)
    line = []
    for k in range(12):  # a straight run: no scan comes back near an earlier one
        parts = flaser.split()
        parts[183] = parts[186] = f"{3.0 * k}"
        parts[189] = parts[191] = f"{k}.0"
        line.append(" ".join(parts))
    (s / "line.log").write_text("\n".join([*text[:2], *line]) + "\n")
    b.expect_warning("bench loops on a log without a true match", "bench", "loops", s / "line.log", "--no-places",
                     "-m", "baseline-histogram", needle="no query has a true match")  # fmt: skip


if __name__ == "__main__":
    raise SystemExit(main())
