"""The second hostile battery of ``scripts/hostile.py`` (run by it; see its docstring for the rules).

Data loss, what does not fit, loaded values, faults, bounded readers,
images read as meant, bags. Every case is its own subprocess; files are
made in the battery's temporary folder.
"""

from __future__ import annotations

import gzip
import json
import math
import os
import shutil
import sqlite3
import struct
import subprocess
import sys
import threading
import zlib
from pathlib import Path
from typing import Any

from hostile import Battery, Result, _carmen_log, _places_file


def battery2(b: Battery, w: Path) -> None:
    d = w / "second"
    d.mkdir()
    log = _carmen_log(d / "rooms.log")
    laser = d / "laser.sqlite"
    b.expect_ok("map (setup)", "map", log, "--db", laser, "--no-calibration", "--no-heading", "--json",
                d / "lt.jsonl", "--queries", d / "lq.jsonl")  # fmt: skip
    train = _places_file(d / "train.jsonl", ["a", "b", "c"])
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
    b.expect_error("learn a place without a pose into a map", "learn", _places_file(d / "np.jsonl", ["far"], poses=False), "--db",
                   _copy(laser, d / "m2.sqlite"), needle="pose", db=d / "m2.sqlite")  # fmt: skip
    # track --graph-from with a concurrent learn: every place stays
    c = d / "conc.sqlite"
    b.expect_ok("learn (setup of the concurrent writers)", "learn", train, "--db", c, "--no-calibration")
    more = _places_file(d / "more.jsonl", [f"x{i}" for i in range(8)], offset=7)
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
                _places_file(d / "w.jsonl", ["w"], offset=30), "--db", wal,
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


def _shifted_log(src: Path, dst: Path, dx: float) -> Path:
    out = []
    for line in src.read_text().splitlines():
        p = line.split()
        if p and p[0] == "FLASER":
            n = int(p[1])
            for k in (2 + n, 2 + n + 3):
                p[k] = f"{float(p[k]) + dx:.3f}"
        elif p and p[0] == "ODOM":
            p[1] = f"{float(p[1]) + dx:.3f}"
        out.append(" ".join(p))
    dst.write_text("\n".join(out) + "\n")
    return dst


def _fit(b: Battery, d: Path, log: Path, laser: Path, image: Path, pano: Path, train: Path) -> None:
    b.expect_error("localize image observations against a laser map", "localize", pano, "--db", laser, "-q",
                   needle="laser")  # fmt: skip
    b.expect_error("localize a laser log against an image database", "localize", log, "--db", image, "-q",
                   needle="image")  # fmt: skip
    b.expect_error("track a laser log against an image database", "track", d / "lq.jsonl", "--db", image, "-q",
                   needle="image", db=image)  # fmt: skip
    b.expect_error("learn laser views into an image database", "learn", d / "lt.jsonl", "--db", image,
                   needle="image", db=image)  # fmt: skip
    far = _shifted_log(log, d / "far.log", 5000.0)
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
    more = _places_file(d / "fmore.jsonl", [f"f{i}" for i in range(40)], offset=3)
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
        many = _places_file(d / "many.jsonl", [f"p{i}" for i in range(2000)])
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
    b.expect_error("features on a 64x20000 PNG", "features", _real_png(d / "tall.png", 64, 20000), timeout=120)


def _real_png(path: Path, w: int, h: int, *, depth: int = 8, rows: Any = None) -> Path:
    """A valid PNG (grey), its rows from ``rows(y)`` (bytes) or zeros."""
    def chunk(t: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + t + data + struct.pack(">I", zlib.crc32(t + data) & 0xFFFFFFFF)

    width = w * depth // 8
    raw = b"".join(b"\0" + (rows(y) if rows else b"\0" * width) for y in range(h))
    ihdr = struct.pack(">IIBBBBB", w, h, depth, 0, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b""))
    return path


# -- images read as they are meant ----------------------------------------------------------------------


def _stripes16(y: int) -> bytes:
    # 16-bit grey stripes between 20000 and 60000 (above 255 everywhere: clipped, all white)
    return b"".join(struct.pack(">H", 20000 if (x // 40) % 2 else 60000) for x in range(1440))


def _images(b: Battery, d: Path) -> None:
    g16 = _real_png(d / "g16.png", 1440, 360, depth=16, rows=_stripes16)
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


def _write_bag(path: Path, *, ranges: Any = None, mount: tuple[float, float, float] = (0.0, 0.0, 0.0),
               topics: tuple[str, ...] = ("/scan",), beacon: bool = False, scales: tuple[float, ...] = (100.0,),
               stamps: int = 4) -> Path:  # fmt: skip
    """A ROS 2 bag: LaserScans (270 deg, 541 beams) of a 6 x 6 m room on ``topics`` (a front lidar, then one
    turned by pi), their mounts on /tf_static, odometry on /odom (the robot moves 0.5 m along x per scan);
    ``ranges`` overrides every range; with ``beacon`` the second lidar sees a 10 cm reflector at -160 deg
    that the first does not cover."""
    import numpy as np
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    n, fov = 541, math.radians(270.0)
    rng = np.random.default_rng(1)

    def header(t: float, frame: str) -> Any:
        return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=int(t), nanosec=round((t % 1) * 1e9)),
                                        frame_id=frame)  # fmt: skip

    def quat(yaw: float) -> Any:
        return T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))

    mounts = [(0.2, 0.0, 0.0), (-0.2, 0.0, math.pi)]
    with Writer(path, version=9) as wr:
        conns = [wr.add_connection(t, "sensor_msgs/msg/LaserScan", typestore=ts) for t in topics]
        c_static = wr.add_connection("/tf_static", "tf2_msgs/msg/TFMessage", typestore=ts)
        c_odom = wr.add_connection("/odom", "nav_msgs/msg/Odometry", typestore=ts)
        links = []
        for k in range(len(topics)):
            x, y, yaw = mount if (k == 0 and mount != (0.0, 0.0, 0.0)) else mounts[k]
            tr = T["geometry_msgs/msg/Transform"](translation=T["geometry_msgs/msg/Vector3"](x=x, y=y, z=0.1),
                                                  rotation=quat(yaw if math.isfinite(yaw) else 0.0))  # fmt: skip
            links.append(T["geometry_msgs/msg/TransformStamped"](header=header(0.5, "base_link"),
                                                                 child_frame_id=f"laser{k}", transform=tr))  # fmt: skip
        wr.write(c_static, int(0.5e9), ts.serialize_cdr(T["tf2_msgs/msg/TFMessage"](transforms=links),
                                                        "tf2_msgs/msg/TFMessage"))  # fmt: skip
        for s in range(stamps):
            zero = T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
            odom = T["nav_msgs/msg/Odometry"](
                header=header(1.0 + 0.1 * s, "odom"), child_frame_id="base_link",
                pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=T["geometry_msgs/msg/Pose"](
                    position=T["geometry_msgs/msg/Point"](x=0.5 * s, y=0.0, z=0.0), orientation=quat(0.0)),
                    covariance=np.zeros(36)),
                twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=T["geometry_msgs/msg/Twist"](
                    linear=zero, angular=zero), covariance=np.zeros(36)),
            )  # fmt: skip
            wr.write(c_odom, int((1.0 + 0.1 * s) * 1e9), ts.serialize_cdr(odom, "nav_msgs/msg/Odometry"))
            for k, conn in enumerate(conns):
                x, y, yaw = mounts[k]
                phi = -fov / 2 + fov / (n - 1) * np.arange(n)
                dx, dy = np.cos(phi + yaw), np.sin(phi + yaw)
                with np.errstate(divide="ignore"):
                    tx = np.where(dx > 0, (3 - x) / dx, np.where(dx < 0, (-3 - x) / dx, np.inf))
                    ty = np.where(dy > 0, (3 - y) / dy, np.where(dy < 0, (-3 - y) / dy, np.inf))
                r = np.minimum(tx, ty)
                inten = scales[min(k, len(scales) - 1)] * (1 + 0.05 * rng.standard_normal(n))
                if beacon and k == 1:
                    ex, ey = x + r * dx, y + r * dy
                    bb = math.radians(-160.0)
                    cx, cy = 3.0 * math.cos(bb) / abs(math.cos(bb)), 3.0 * math.tan(bb) * math.copysign(1, math.cos(bb))
                    inten[np.hypot(ex - cx, ey - cy) <= 0.05] *= 6
                rr = np.full(n, ranges, dtype=np.float32) if ranges is not None else r.astype(np.float32)
                t = 1.0 + 0.1 * s + 0.01 * k
                msg = T["sensor_msgs/msg/LaserScan"](header=header(t, f"laser{k}"), angle_min=-fov / 2,
                                                     angle_max=fov / 2, angle_increment=fov / (n - 1),
                                                     time_increment=0.0, scan_time=0.1, range_min=0.05,
                                                     range_max=30.0, ranges=rr,
                                                     intensities=inten.astype(np.float32))  # fmt: skip
                wr.write(conn, int(t * 1e9), ts.serialize_cdr(msg, "sensor_msgs/msg/LaserScan"))
    return path


def _bags(b: Battery, d: Path) -> None:
    try:
        import rosbags  # noqa: F401
    except ImportError:
        return
    nan_bag = _write_bag(d / "nan-bag", ranges=float("nan"), stamps=8)
    b.expect_error("map a bag whose ranges are all NaN", "map", nan_bag, "--db", d / "nan.sqlite", "--pose-source",
                   "odom", "--no-calibration", needle="return")  # fmt: skip
    far_bag = _write_bag(d / "far-bag", ranges=100.0, stamps=8)
    b.expect_error("map a bag whose ranges are all beyond range_max", "map", far_bag, "--db", d / "far.sqlite",
                   "--pose-source", "odom", "--no-calibration", needle="return")  # fmt: skip
    inf_bag = _write_bag(d / "inf-bag", mount=(math.inf, math.nan, 0.0))
    b.expect_error("features of a bag with a lidar mount at (inf, nan)", "features", inf_bag, needle="translation")
    good = _write_bag(d / "good-bag")
    dmg = d / "damaged-bag"
    shutil.copytree(good, dmg)
    db3 = next(dmg.glob("*.db3"), None) or next(dmg.glob("*.mcap"), None)
    if db3 is not None:
        raw = bytearray(db3.read_bytes())
        for k in range(len(raw) // 3, len(raw) // 3 + 4096, 7):
            raw[k] ^= 0x5A
        db3.write_bytes(bytes(raw))
        b.expect_error("features of a bag with damaged messages", "features", dmg)
    two = _write_bag(d / "two-lidars", topics=("/scan_front", "/scan_back"), beacon=True, scales=(1000.0, 40.0))

    out = d / "two.jsonl"

    def beacon(r: Result) -> str:
        n = [len(rec.get("features", {}).get("B", [])) for rec in _records(out)]
        return "" if n and min(n) > 0 else f"no beacon in the merged scans ({n})"

    b.expect_ok("features of two merged lidars keep the back lidar's beacon", "features", two, "--topic",
                "/scan_front", "--topic", "/scan_back", "--pose-source", "none", "--json", out, check=beacon)  # fmt: skip
