"""Red-team sweep of every ``telesmooth`` entry point with hostile and mistaken input.

Run by the suite (``tests/test_bad_input_sweep.py``) and on its own; the focused
``tests/test_bad_input_*.py`` files hold the unit tests. A script
that tries every case below and prints a table: one row per case with what happened. Run it
from a checkout with its virtual environment::

    .venv/bin/python tests/bad_input_redteam.py [--only ID_PREFIX] [--markdown]

Each case runs ``telesmooth.scripts.cli.main(argv)`` in a forked child of this process (the
imports are paid once), in its own scratch folder, with an address-space limit and a time
limit. A case passes ("ok") when the command exits with status 2, its last stderr line is one
error line of at most 300 characters that contains the expected words, no traceback was
printed, every input file kept its bytes, and no output it names exists afterwards. Cases that
must succeed are marked ``expect="ok"`` (status 0).

Outcomes: ok, TRACEBACK, HANG (time limit), CRASH (killed, e.g. by the memory limit), STATUS
(another exit status), LONG (message over 300 characters or several lines), UNNAMED (the
message lacks a word it must name), LEAK (key material in the output), WROTE (an output left
behind), CHANGED (an input file modified).
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import io
import os
import resource
import signal
import sys
import tempfile
import time
import zipfile
from pathlib import Path

import numpy as np

MAX_LINE = 300
TIME_LIMIT_S = 60.0
MEMORY_LIMIT_BYTES = 6 << 30     # on top of what the parent already maps
HEX_KEY = "8f" * 32


@dataclasses.dataclass
class Case:
    id: str
    cls: str                       # the class: "2" (newcomer path) or "3.1" ... "3.7"
    argv: list
    setup: object = None           # callable(folder) run before the command
    inputs: tuple = ()             # files whose bytes must not change
    absent: tuple = ("out",)       # paths that must not exist afterwards
    must_name: tuple = ()          # words the error line must contain
    expect: str = "error"          # "error" (status 2) or "ok" (status 0)
    env: dict = dataclasses.field(default_factory=dict)
    forbid: tuple = ()             # strings that must not appear (key material)
    time_limit_s: float = TIME_LIMIT_S
    note: str = ""


# --- fixtures ---------------------------------------------------------------------------------

def joint_csv(path, rows=40, names=("a", "b"), step=0.25, jump=None, header=None):
    t = step * np.arange(rows)
    q = 0.1 * np.sin(np.outer(t, np.arange(1, len(names) + 1)) / 3.0)
    if jump is not None:
        q[rows // 2:, 0] += jump
    lines = [header or ",".join(("t",) + tuple(names))]
    lines += [",".join(repr(float(v)) for v in (ti, *qi)) for ti, qi in zip(t, q)]
    Path(path).write_text("\n".join(lines) + "\n")


def base_files(folder: Path):
    joint_csv(folder / "in.csv")
    (folder / "scn.yaml").write_text("Defaults: {}\n")
    (folder / "dir").mkdir()
    key = folder / "k.key"
    key.write_text(HEX_KEY + "\n")
    key.chmod(0o600)
    (folder / "link.csv").symlink_to("in.csv")


def fifo(name):
    def make(folder):
        os.mkfifo(folder / name)
    return make


def write(name, data, mode=None):
    def make(folder):
        path = folder / name
        path.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(data, str):
            path.write_text(data)
        else:
            path.write_bytes(data)
        if mode is not None:
            path.chmod(mode)
    return make


def sparse(name, size):
    def make(folder):
        with open(folder / name, "wb") as handle:
            handle.truncate(size)
    return make


def npz_bomb(name, members=1, uncompressed=2 << 30):
    """A zip whose .npy member claims (and inflates to) ``uncompressed`` bytes of zeros."""
    def make(folder):
        header = io.BytesIO()
        count = uncompressed // 8
        np.lib.format.write_array_header_1_0(
            header, {"descr": "<f8", "fortran_order": False, "shape": (count,)})
        with zipfile.ZipFile(folder / name, "w", zipfile.ZIP_DEFLATED) as archive:
            for index in range(members):
                with archive.open(f"t_s{index or ''}.npy", "w", force_zip64=True) as member:
                    member.write(header.getvalue())
                    chunk = bytes(1 << 20)
                    for _ in range(uncompressed >> 20):
                        member.write(chunk)
    return make


def npz_lying_header(name):
    """A tiny zip whose .npy header claims 10^12 doubles."""
    def make(folder):
        header = io.BytesIO()
        np.lib.format.write_array_header_1_0(
            header, {"descr": "<f8", "fortran_order": False, "shape": (10**12,)})
        with zipfile.ZipFile(folder / name, "w", zipfile.ZIP_DEFLATED) as archive:
            archive.writestr("t_s.npy", header.getvalue() + bytes(64))
    return make


def many(*makers):
    def make(folder):
        for maker in makers:
            maker(folder)
    return make


def billion_laughs(levels=9):
    lines = ['a0: &a0 ["lol","lol","lol","lol","lol","lol","lol","lol","lol","lol"]']
    for level in range(1, levels + 1):
        refs = ",".join(f"*a{level - 1}" for _ in range(10))
        lines.append(f"a{level}: &a{level} [{refs}]")
    lines.append(f"Defaults: {{haptic: {{lasa_mapping: *a{levels}}}}}")
    return "\n".join(lines) + "\n"


def deep(levels=100_000):
    return "Defaults: " + "[" * levels + "]" * levels + "\n"


# --- cases ------------------------------------------------------------------------------------

LIMITS = ["--acc-max", "0.05", "--jerk-max", "0.1"]
SMOOTH = ["smooth", "in.csv", "-o", "out/o.csv", *LIMITS]
SIM = ["simulate", "--out", "out"]
MEMQ = ["--lcm-url", "memq://"]


def cases() -> list[Case]:
    c = []

    def add(*args, **kwargs):
        c.append(Case(*args, **kwargs))

    # 2: the newcomer path
    add("keygen-no-folder", "2", ["keygen", "home/.telesmooth/uplink.key"], expect="ok",
        absent=())
    add("keygen-exists", "2", ["keygen", "k.key"], inputs=("k.key",), must_name=("k.key",),
        absent=())
    add("keygen-is-dir", "2", ["keygen", "dir"], absent=(), must_name=("dir",))
    add("keygen-parent-file", "2", ["keygen", "in.csv/uplink.key"], inputs=("in.csv",),
        absent=(), must_name=("in.csv",))
    add("keygen-fifo", "2", ["keygen", "f"], setup=fifo("f"), absent=(), must_name=("f",))
    add("demo-unknown-shape", "2", ["demo", "--shape", "Sshap", "--out", "out"],
        must_name=("--shape", "Sshap"))
    add("demo-bad-index", "2", ["demo", "--demo-index", "9", "--out", "out"],
        must_name=("--demo-index", "9"))
    add("demo-neg-index", "2", ["demo", "--demo-index", "-1", "--out", "out"],
        must_name=("--demo-index", "-1"))
    add("smooth-unknown-method", "2", [*SMOOTH, "--method", "foo"], inputs=("in.csv",),
        must_name=("--method", "foo"))
    add("compare-unknown-method", "2", ["compare", "--methods", "foo", "--out", "out"],
        must_name=("--methods", "foo"))
    add("compare-no-method", "2", ["compare", "--methods", ",", "--out", "out"],
        must_name=("--methods",))
    add("experiment-unknown-shape", "2",
        ["experiment", "--shapes", "Sshap", "--out", "out", "--workers", "0"],
        must_name=("--shapes", "Sshap"))
    add("experiment-unknown-method", "2",
        ["experiment", "--quick", "--methods", "foo", "--out", "out", "--workers", "0"],
        must_name=("--methods", "foo"))
    add("experiment-bad-demos", "2",
        ["experiment", "--quick", "--demos", "9", "--out", "out", "--workers", "0"],
        must_name=("--demos", "9"))
    add("simulate-unknown-shape-out", "2",
        [*SIM, "--scenario-text", "{haptic: {lasa_shape: Sshap}}"],
        must_name=("haptic.lasa_shape", "Sshap"))
    add("foresight-unknown-shape", "2",
        ["foresight", "--scenario-text", "{haptic: {lasa_shape: Sshap}}", "--out", "out"],
        must_name=("haptic.lasa_shape", "Sshap"))

    # 3.1: files destroyed or half-written
    add("smooth-o-is-input", "3.1", ["smooth", "in.csv", "-o", "in.csv", *LIMITS],
        inputs=("in.csv",), absent=(), must_name=("-o", "in.csv"))
    add("smooth-o-symlink-to-input", "3.1", ["smooth", "in.csv", "-o", "link.csv", *LIMITS],
        inputs=("in.csv",), absent=(), must_name=("-o", "link.csv"))
    add("smooth-o-dotdot-input", "3.1", ["smooth", "in.csv", "-o", "dir/../in.csv", *LIMITS],
        inputs=("in.csv",), absent=(), must_name=("-o",))
    add("smooth-metrics-is-input", "3.1", [*SMOOTH, "--metrics", "in.csv"],
        inputs=("in.csv",), must_name=("--metrics", "in.csv"))
    add("smooth-sigma-store-is-input", "3.1",
        [*SMOOTH, "--method", "online-cks", "--operator", "bob", "--sigma-store", "in.csv"],
        inputs=("in.csv",), must_name=("--sigma-store", "in.csv"))
    add("smooth-o-is-metrics", "3.1", ["smooth", "in.csv", "-o", "out.csv", *LIMITS,
                                       "--metrics", "out.csv"],
        absent=("out.csv",), must_name=("--metrics", "out.csv"))
    add("smooth-o-is-sigma-store", "3.1",
        ["smooth", "in.csv", "-o", "s.json", *LIMITS, "--operator", "bob", "--sigma-store",
         "s.json"], absent=("s.json",), must_name=("s.json",))
    add("smooth-o-is-dir", "3.1", ["smooth", "in.csv", "-o", "dir", *LIMITS],
        inputs=("in.csv",), absent=("dir/in.csv",), must_name=("-o", "dir"))
    add("smooth-o-parent-is-file", "3.1", ["smooth", "in.csv", "-o", "in.csv/o.csv", *LIMITS],
        inputs=("in.csv",), absent=(), must_name=("-o", "in.csv"))
    add("smooth-metrics-is-dir", "3.1", [*SMOOTH, "--metrics", "dir"],
        must_name=("--metrics", "dir"))
    add("smooth-metrics-parent-file", "3.1", [*SMOOTH, "--metrics", "in.csv/m.json"],
        inputs=("in.csv",), must_name=("--metrics", "in.csv"))
    add("smooth-sigma-store-is-dir", "3.1",
        [*SMOOTH, "--operator", "bob", "--sigma-store", "dir"], must_name=("--sigma-store",))
    add("smooth-o-dev-null-ok", "3.1", ["smooth", "in.csv", "-o", "/dev/null", *LIMITS],
        inputs=("in.csv",), absent=(), expect="ok")
    add("demo-out-is-file", "3.1", ["demo", "--out", "in.csv"], inputs=("in.csv",),
        absent=(), must_name=("--out", "in.csv"))
    add("demo-out-parent-file", "3.1", ["demo", "--out", "in.csv/sub"], inputs=("in.csv",),
        absent=(), must_name=("--out", "in.csv"))
    add("simulate-out-holds-scenario", "3.1",
        ["simulate", "--scenario", "out/scenarios.yaml", "--out", "out", "--duration", "2"],
        setup=write("out/scenarios.yaml", "Defaults: {}\n"), inputs=("out/scenarios.yaml",),
        expect="ok", note="an input inside --out is kept: the report writes other names")
    add("simulate-out-is-scenario", "3.1",
        ["simulate", "--scenario", "scn.yaml", "--out", "scn.yaml"], inputs=("scn.yaml",),
        absent=(), must_name=("--out", "scn.yaml"))
    add("simulate-out-holds-haptic-file", "3.1",
        ["simulate", "--scenario-text", "{haptic: {source: file, file: out/telemetry.csv}}",
         "--out", "out", "--duration", "2"],
        setup=write("out/telemetry.csv", "t,x_m,y_m,phi_rad\n0,0.7,0,0\n0.01,0.7,0,0\n"),
        inputs=("out/telemetry.csv",), absent=("out/report.md",),
        must_name=("--out", "telemetry.csv"))
    add("ground-out-is-file", "3.1",
        ["ground", *MEMQ, "--no-auth", "--out", "in.csv", "--duration", "1", "--realtime", "0",
         "--resume-wait", "0"], inputs=("in.csv",), absent=(), must_name=("--out", "in.csv"))
    add("onboard-out-is-key-folder", "3.1",
        ["onboard", *MEMQ, "--uplink-key", "out/k.key", "--out", "out", "--duration", "0.5",
         "--realtime", "0"], setup=write("out/k.key", HEX_KEY + "\n", 0o600),
        inputs=("out/k.key",), absent=("out/onboard_counts.json",), expect="ok")
    add("relay-report-is-dir", "3.1",
        ["link-relay", "--in-url", "memq://a", "--out-url", "memq://b", "--duration", "0.1",
         "--report", "dir", "--quiet"], absent=(), must_name=("--report", "dir"))
    add("relay-report-parent-file", "3.1",
        ["link-relay", "--in-url", "memq://a", "--out-url", "memq://b", "--duration", "0.1",
         "--report", "in.csv/r.json", "--quiet"], inputs=("in.csv",), absent=(),
        must_name=("--report", "in.csv"))
    add("bench-out-is-file", "3.1",
        ["bench", "--out", "in.csv", "--max-n", "100", "--repeat", "1", "--ticks", "5",
         "--sim-duration", "0"], inputs=("in.csv",), absent=(), must_name=("--out", "in.csv"))

    add("smooth-o-dev-full", "3.1", ["smooth", "in.csv", "-o", "/dev/full", *LIMITS],
        inputs=("in.csv",), absent=(), must_name=("/dev/full", "No space left"))
    add("smooth-metrics-dev-full", "3.1", [*SMOOTH, "--metrics", "/dev/full"],
        inputs=("in.csv",), must_name=("/dev/full",))
    add("demo-out-dev-null", "3.1", ["demo", "--out", "/dev/null"], absent=(),
        must_name=("--out = '/dev/null'",))
    add("simulate-meshcat-out-is-file", "3.1", ["simulate", "--meshcat", "--out", "in.csv"],
        inputs=("in.csv",), absent=(), must_name=("--out", "in.csv"))
    add("keygen-empty-path", "2", ["keygen", ""], absent=(), must_name=("keygen",))

    # 3.2: unbounded resources
    add("smooth-input-dev-zero", "3.2", ["smooth", "/dev/zero", "-o", "out/o.csv", *LIMITS],
        must_name=("/dev/zero",))
    add("smooth-input-urandom", "3.2", ["smooth", "/dev/urandom", "-o", "out/o.csv", *LIMITS],
        must_name=("/dev/urandom",))
    add("smooth-input-fifo", "3.2", ["smooth", "f", "-o", "out/o.csv", *LIMITS],
        setup=fifo("f"), must_name=("f",))
    add("smooth-input-sparse-1GB", "3.2", ["smooth", "big.csv", "-o", "out/o.csv", *LIMITS],
        setup=sparse("big.csv", 1 << 30), must_name=("big.csv",))
    add("smooth-input-many-rows", "3.2", ["smooth", "rows.csv", "-o", "out/o.csv", *LIMITS],
        setup=write("rows.csv", "t,a\n" + "".join(f"{k},0\n" for k in range(3_000_000))),
        must_name=("rows.csv",))
    add("smooth-input-wide-header", "3.2", ["smooth", "wide.csv", "-o", "out/o.csv", *LIMITS],
        setup=write("wide.csv", "t," + ",".join(f"j{k}" for k in range(300_000))
                    + "\n0" + ",0" * 300_000 + "\n1" + ",0" * 300_000 + "\n"),
        must_name=("wide.csv",))
    add("smooth-input-one-long-line", "3.2", ["smooth", "line.csv", "-o", "out/o.csv", *LIMITS],
        setup=write("line.csv", "t,a\n" + "0," * 8_000_000 + "\n"), must_name=("line.csv",))
    add("smooth-lag-10000", "3.2", [*SMOOTH, "--method", "bmfls", "--lag", "10000"],
        must_name=("--lag", "10000"))
    add("smooth-lag-huge-online", "3.2", [*SMOOTH, "--lag", "100000000"],
        must_name=("--lag",))
    add("smooth-sigma-store-dev-zero", "3.2",
        [*SMOOTH, "--operator", "bob", "--sigma-store", "/dev/zero"],
        must_name=("--sigma-store", "/dev/zero"))
    add("smooth-sigma-store-deep-json", "3.2",
        [*SMOOTH, "--operator", "bob", "--sigma-store", "s.json"],
        setup=write("s.json", "[" * 200_000 + "]" * 200_000), inputs=("s.json",),
        must_name=("s.json",))
    add("smooth-sigma-store-huge", "3.2",
        [*SMOOTH, "--operator", "bob", "--sigma-store", "s.json"],
        setup=sparse("s.json", 300 << 20), must_name=("s.json",))
    add("scenario-billion-laughs", "3.2", [*SIM, "--scenario", "b.yaml"],
        setup=write("b.yaml", billion_laughs()), inputs=("b.yaml",), must_name=("b.yaml",))
    add("scenario-text-billion-laughs", "3.2",
        [*SIM, "--scenario-text", billion_laughs(7).replace("\n", "\n")],
        must_name=("--scenario-text",))
    add("scenario-deep-nesting", "3.2", [*SIM, "--scenario", "d.yaml"],
        setup=write("d.yaml", deep()), inputs=("d.yaml",), must_name=("d.yaml",))
    add("scenario-megabyte-string", "3.2", [*SIM, "--scenario", "m.yaml"],
        setup=write("m.yaml", "Defaults: {arm: " + "x" * (4 << 20) + "}\n"),
        inputs=("m.yaml",), must_name=("m.yaml",))
    add("scenario-megabyte-key", "3.2", [*SIM, "--scenario", "m.yaml"],
        setup=write("m.yaml", "Defaults: {" + "k" * (2 << 20) + ": 1}\n"),
        inputs=("m.yaml",), must_name=("m.yaml",))
    add("scenario-dev-zero", "3.2", [*SIM, "--scenario", "/dev/zero"],
        must_name=("/dev/zero",))
    add("scenario-fifo", "3.2", [*SIM, "--scenario", "f"], setup=fifo("f"), must_name=("f",))
    add("scenario-sparse-1GB", "3.2", [*SIM, "--scenario", "big.yaml"],
        setup=sparse("big.yaml", 1 << 30), must_name=("big.yaml",))
    add("haptic-file-dev-zero", "3.2",
        [*SIM, "--scenario-text", "{haptic: {source: file, file: /dev/zero}}"],
        must_name=("haptic.file", "/dev/zero"))
    add("haptic-file-fifo-npz", "3.2",
        [*SIM, "--scenario-text", "{haptic: {source: file, file: f.npz}}"],
        setup=fifo("f.npz"), must_name=("haptic.file", "f.npz"))
    add("haptic-npz-bomb", "3.2",
        [*SIM, "--scenario-text", "{haptic: {source: file, file: bomb.npz}}"],
        setup=npz_bomb("bomb.npz"), inputs=("bomb.npz",), must_name=("bomb.npz",))
    add("haptic-npz-lying-header", "3.2",
        [*SIM, "--scenario-text", "{haptic: {source: file, file: lie.npz}}"],
        setup=npz_lying_header("lie.npz"), inputs=("lie.npz",), must_name=("lie.npz",))
    add("key-dev-zero", "3.2",
        ["onboard", *MEMQ, "--uplink-key", "/dev/zero", "--duration", "1"],
        absent=(), must_name=("/dev/zero",))
    add("key-fifo", "3.2", ["onboard", *MEMQ, "--uplink-key", "f", "--duration", "1"],
        setup=fifo("f"), absent=(), must_name=("f",))
    add("key-sparse-1GB", "3.2", ["onboard", *MEMQ, "--uplink-key", "big.key", "--duration",
                                  "1"], setup=many(sparse("big.key", 1 << 30)),
        absent=(), must_name=("big.key",))
    add("relay-link-billion-laughs", "3.2",
        ["link-relay", "--in-url", "memq://a", "--out-url", "memq://b", "--duration", "0.1",
         "--link", billion_laughs(7).replace("Defaults: {haptic: {lasa_mapping: *a7}}",
                                             "delay_s: *a7")],
        absent=(), must_name=("--link",))
    add("relay-link-deep", "3.2",
        ["link-relay", "--in-url", "memq://a", "--out-url", "memq://b", "--duration", "0.1",
         "--link", "[" * 50_000 + "]" * 50_000], absent=(), must_name=("--link",))
    add("bench-max-n-huge", "3.2", ["bench", "--out", "out", "--max-n", "-5"],
        must_name=("--max-n",))
    add("bench-sim-duration-huge", "3.2", ["bench", "--out", "out", "--max-n", "100",
                                           "--repeat", "1", "--ticks", "5",
                                           "--sim-duration", "1e9"],
        must_name=("--sim-duration",))
    add("foresight-step-0", "3.2", ["foresight", "--step", "0", "--out", "out"],
        must_name=("--step", "0"))
    add("experiment-settle-huge", "3.2",
        ["experiment", "--quick", "--settle", "1e12", "--out", "out", "--workers", "0"],
        must_name=("--settle",))

    # 3.3: tracebacks
    add("smooth-input-missing", "3.3", ["smooth", "nope.csv", "-o", "out/o.csv", *LIMITS],
        must_name=("nope.csv",))
    add("smooth-input-is-dir", "3.3", ["smooth", "dir", "-o", "out/o.csv", *LIMITS],
        must_name=("dir",))
    add("smooth-input-empty", "3.3", ["smooth", "e.csv", "-o", "out/o.csv", *LIMITS],
        setup=write("e.csv", ""), must_name=("e.csv", "empty"))
    add("smooth-input-header-only", "3.3", ["smooth", "h.csv", "-o", "out/o.csv", *LIMITS],
        setup=write("h.csv", "t,a\n"), must_name=("h.csv",))
    add("smooth-sigma-store-operator-not-mapping", "3.3",
        [*SMOOTH, "--operator", "bob", "--sigma-store", "s.json"],
        setup=write("s.json", '{"format": "telesmooth-operator-sigma/1", "operators": '
                              '{"bob": [1, 2]}}'), inputs=("s.json",), must_name=("s.json",))
    add("smooth-operator-empty", "3.3",
        [*SMOOTH, "--operator", " ", "--sigma-store", "s.json"], absent=("out", "s.json"),
        must_name=("operator",))
    add("scenario-name-empty", "3.3", [*SIM, "--scenario-name", "", "--duration", "2"],
        expect="ok", absent=(), note="empty name: the default entry")
    add("compare-solver-bad", "3.3", ["compare", "--solver", "cplex", "--out", "out"],
        must_name=("--solver",))
    add("foresight-method-bad", "3.3", ["foresight", "--method", "magic", "--out", "out"],
        must_name=("--method",))
    add("smooth-ruckig-tiny-limits", "3.3",
        ["smooth", "in.csv", "-o", "out/o.csv", "--method", "ruckig", "--acc-max", "1e-300",
         "--jerk-max", "1e-300", "--vel-max", "1e-300"], inputs=("in.csv",),
        must_name=("ruckig",))
    add("smooth-ruckig-huge-limits", "3.3",
        ["smooth", "in.csv", "-o", "out/o.csv", "--method", "ruckig", "--acc-max", "1e300",
         "--jerk-max", "1e300", "--vel-max", "1e300"], inputs=("in.csv",),
        must_name=("ruckig",), expect="error")
    add("smooth-ruckig-huge-step", "3.3",
        ["smooth", "big.csv", "-o", "out/o.csv", "--method", "ruckig", *LIMITS],
        setup=lambda folder: joint_csv(folder / "big.csv", jump=1e200), inputs=("big.csv",),
        must_name=("big.csv",))
    add("smooth-ruckig-long-step", "3.3",
        ["smooth", "far.csv", "-o", "out/o.csv", "--method", "ruckig", "--acc-max", "1e-3",
         "--jerk-max", "1e-3"],
        setup=lambda folder: joint_csv(folder / "far.csv", jump=9e5), inputs=("far.csv",),
        must_name=("ruckig", "joint"))
    add("smooth-dt-zero", "3.3", [*SMOOTH, "--dt", "0"], must_name=("--dt", "0"))
    add("smooth-dt-negative", "3.3", [*SMOOTH, "--dt", "-1"], must_name=("--dt", "-1"))
    add("smooth-dt-nan", "3.3", [*SMOOTH, "--dt", "nan"], must_name=("--dt", "nan"))
    add("smooth-sigma-store-not-json", "3.3",
        [*SMOOTH, "--operator", "bob", "--sigma-store", "s.json"],
        setup=write("s.json", "not json"), inputs=("s.json",), must_name=("s.json",))
    add("smooth-sigma-store-bad-utf8", "3.3",
        [*SMOOTH, "--operator", "bob", "--sigma-store", "s.json"],
        setup=write("s.json", b"\xff\xfe{}"), inputs=("s.json",), must_name=("s.json",))
    add("smooth-sigma-store-list", "3.3",
        [*SMOOTH, "--operator", "bob", "--sigma-store", "s.json"],
        setup=write("s.json", "[1, 2]"), inputs=("s.json",), must_name=("s.json",))
    add("smooth-sigma-store-bad-joint-sigma", "3.3",
        [*SMOOTH, "--operator", "bob", "--sigma-store", "s.json"],
        setup=write("s.json", '{"format": "telesmooth-operator-sigma/1", "operators": '
                              '{"bob": {"a": 1e999, "b": 1}}}'),
        inputs=("s.json",), must_name=("s.json",))
    add("smooth-rho-2", "3.3", [*SMOOTH, "--rho", "2"], must_name=("--rho", "2"))
    add("smooth-sigma-min-negative", "3.3", [*SMOOTH, "--sigma-min", "-1"],
        must_name=("--sigma-min", "-1"))
    add("smooth-lag-negative", "3.3", [*SMOOTH, "--lag", "-1"], must_name=("--lag", "-1"))
    add("smooth-lag-zero-bmfls", "3.3", [*SMOOTH, "--method", "bmfls", "--lag", "0"],
        expect="ok", note="lag 0: the filter")
    add("smooth-lag-past-recording", "3.2", [*SMOOTH, "--method", "bmfls", "--lag", "500"],
        must_name=("--lag", "500"))
    add("smooth-acc-zero", "3.3", ["smooth", "in.csv", "-o", "out/o.csv", "--acc-max", "0",
                                   "--jerk-max", "0.1"], must_name=("--acc-max", "0"))
    add("smooth-acc-inf-offline", "3.3",
        ["smooth", "in.csv", "-o", "out/o.csv", "--acc-max", "inf", "--jerk-max", "0.1",
         "--method", "offline-cks"], must_name=("--acc-max",), expect="error")
    add("smooth-two-rows", "3.3", ["smooth", "two.csv", "-o", "out/o.csv", *LIMITS,
                                   "--method", "offline-cks"],
        setup=lambda folder: joint_csv(folder / "two.csv", rows=2), inputs=("two.csv",),
        expect="ok", absent=())
    add("smooth-three-rows-every-method", "3.3",
        ["smooth", "three.csv", "-o", "out/o.csv", *LIMITS, "--method", "online-hard",
         "--vel-max", "1"], setup=lambda folder: joint_csv(folder / "three.csv", rows=3),
        expect="ok", absent=())
    add("smooth-huge-values", "3.3",
        ["smooth", "big.csv", "-o", "out/o.csv", *LIMITS, "--method", "offline-cks"],
        setup=lambda folder: joint_csv(folder / "big.csv", jump=1e300), inputs=("big.csv",),
        must_name=("big.csv",))
    add("smooth-huge-values-online", "3.3",
        ["smooth", "big.csv", "-o", "out/o.csv", *LIMITS, "--method", "online-hard"],
        setup=lambda folder: joint_csv(folder / "big.csv", jump=1e300), inputs=("big.csv",),
        must_name=("big.csv",))
    add("smooth-link-lengths-bad", "3.3", [*SMOOTH, "--metrics", "out/m.json",
                                           "--link-lengths", "1,-1"],
        must_name=("--link-lengths",))
    add("scenario-int-key", "3.3", [*SIM, "--scenario-text", "{1: 2}"],
        must_name=("--scenario-text", "1"))
    add("scenario-null-key", "3.3", [*SIM, "--scenario-text", "{~: 2}"],
        must_name=("--scenario-text",))
    add("scenario-mixed-keys", "3.3", [*SIM, "--scenario-text", "{arm: space_arm, 3: 4}"],
        must_name=("--scenario-text", "3"))
    add("scenario-nested-int-key", "3.3", [*SIM, "--scenario-text", "{haptic: {1: 2}}"],
        must_name=("haptic",))
    add("scenario-file-int-key", "3.3", [*SIM, "--scenario", "i.yaml"],
        setup=write("i.yaml", "1: {}\nDefaults: {}\n"), must_name=("i.yaml",))
    add("scenario-file-list-key", "3.3", [*SIM, "--scenario", "i.yaml"],
        setup=write("i.yaml", "Defaults: {? [a, b] : 1}\n"), must_name=("i.yaml",))
    add("scenario-top-list", "3.3", [*SIM, "--scenario-text", "[1, 2]"],
        must_name=("--scenario-text",))
    add("scenario-entry-not-mapping", "3.3", [*SIM, "--scenario", "i.yaml"],
        setup=write("i.yaml", "Defaults: 3\n"), must_name=("Defaults",))
    add("scenario-tag", "3.3", [*SIM, "--scenario-text", "{haptic: !Foo {a: 1}}"],
        must_name=("--scenario-text",))
    add("scenario-unknown-name", "3.3", [*SIM, "--scenario-name", "Nope"],
        must_name=("--scenario-name", "Nope"))
    add("scenario-missing-file", "3.3", [*SIM, "--scenario", "nope.yaml"],
        must_name=("nope.yaml",))
    add("scenario-dir", "3.3", [*SIM, "--scenario", "dir"], must_name=("dir",))
    add("scenario-bad-utf8", "3.3", [*SIM, "--scenario", "u.yaml"],
        setup=write("u.yaml", b"Defaults: {arm: \xff}\n"), must_name=("u.yaml",))
    add("scenario-period-zero", "3.3",
        [*SIM, "--scenario-text", "{haptic: {period_s: 0}}"],
        must_name=("haptic.period_s", "0"))
    add("scenario-period-negative", "3.3",
        [*SIM, "--scenario-text", "{haptic: {period_s: -100}}"],
        must_name=("haptic.period_s", "-100"))
    add("scenario-fifo-period-zero", "3.3",
        [*SIM, "--scenario-text", "{fifo: {period_s: 0}, smoother: {period_s: 0}, "
         "uplink: {period_s: 0}}"], must_name=("period_s",))
    add("scenario-duration-inf", "3.3",
        [*SIM, "--scenario-text", "{simulation_duration_s: .inf}"],
        must_name=("simulation_duration_s", "inf"))
    add("simulate-duration-inf", "3.3", [*SIM, "--duration", "inf"],
        must_name=("--duration", "inf"))
    add("simulate-duration-nan", "3.3", [*SIM, "--duration", "nan"],
        must_name=("--duration", "nan"))
    add("simulate-shorter-than-fifo", "3.3", [*SIM, "--duration", "0.1"],
        must_name=("--duration", "0.1"))
    add("scenario-duration-short", "3.3",
        [*SIM, "--scenario-text", "{simulation_duration_s: 0.05}"],
        must_name=("simulation_duration_s", "0.05"))
    add("scenario-settle-inf", "3.3", [*SIM, "--scenario-text", "{settle_s: .inf}"],
        must_name=("settle_s",))
    add("scenario-lasa-demo-99", "3.3", [*SIM, "--scenario-text", "{haptic: {lasa_demo: 99}}"],
        must_name=("haptic.lasa_demo", "99"))
    add("scenario-arm-int", "3.3", [*SIM, "--scenario-text", "{arm: 1}"],
        must_name=("arm", "1"))
    add("scenario-haptic-list", "3.3", [*SIM, "--scenario-text", "{haptic: [1, 2]}"],
        must_name=("haptic",))
    add("scenario-haptic-file-missing", "3.3",
        [*SIM, "--scenario-text", "{haptic: {source: file, file: nope.csv}}"],
        must_name=("haptic.file", "nope.csv"))
    add("scenario-haptic-file-dir", "3.3",
        [*SIM, "--scenario-text", "{haptic: {source: file, file: dir}}"],
        must_name=("haptic.file", "dir"))
    add("scenario-haptic-file-joint-csv", "3.3",
        [*SIM, "--scenario-text", "{haptic: {source: file, file: in.csv}}"],
        must_name=("haptic.file", "in.csv"))
    add("scenario-synthetic-zero-duration", "3.3",
        [*SIM, "--scenario-text", "{haptic: {source: synthetic, synthetic: {duration_s: 0}}}"],
        must_name=("haptic.synthetic.duration_s",))
    add("scenario-initial-position-nan", "3.3",
        [*SIM, "--scenario-text", "{initial_position_rad: [.nan, 0, 0]}"],
        must_name=("initial_position_rad",))
    add("scenario-onboard-step-negative", "3.3",
        [*SIM, "--scenario-text", "{onboard: {time_step_s: -1}}"],
        must_name=("onboard.time_step_s",))
    add("scenario-fifo-delay-huge", "3.2",
        [*SIM, "--scenario-text", "{fifo: {delay_s: 10000}, smoother: {lag: 40000}}"],
        must_name=("lag",))
    add("scenario-settle-huge", "3.2", [*SIM, "--scenario-text", "{settle_s: 1e9}"],
        must_name=("settle_s",))
    add("scenario-workspace-bad", "3.3", [*SIM, "--scenario-text", "{workspace: 3}"],
        must_name=("workspace",))
    add("ground-duration-inf", "3.3",
        ["ground", *MEMQ, "--no-auth", "--duration", "inf", "--resume-wait", "0"],
        absent=(), must_name=("--duration", "inf"))
    add("ground-realtime-nan", "3.3",
        ["ground", *MEMQ, "--no-auth", "--realtime", "nan", "--resume-wait", "0"],
        absent=(), must_name=("--realtime", "nan"))
    add("ground-resume-wait-inf", "3.3",
        ["ground", *MEMQ, "--no-auth", "--resume-wait", "inf"],
        absent=(), must_name=("--resume-wait", "inf"))
    add("ground-bad-url", "3.3",
        ["ground", "--lcm-url", "bogus://x", "--no-auth", "--duration", "1", "--resume-wait",
         "0"], absent=(), must_name=("bogus://x",))
    add("onboard-bad-url", "3.3",
        ["onboard", "--lcm-url", "udpm://300.1.2.3:7667?ttl=0", "--no-auth", "--duration",
         "1"], absent=(), must_name=("300.1.2.3",))
    add("onboard-no-duration", "3.3", ["onboard", *MEMQ, "--no-auth"], absent=(),
        must_name=("--duration",))
    add("onboard-duration-inf", "3.3",
        ["onboard", *MEMQ, "--no-auth", "--duration", "inf"], absent=(),
        must_name=("--duration", "inf"), time_limit_s=30)
    add("experiment-plant-step-negative", "3.3",
        ["experiment", "--quick", "--plant-step", "-0.001", "--out", "out", "--workers", "0"],
        must_name=("--plant-step", "-0.001"))
    add("experiment-plant-step-nan", "3.3",
        ["experiment", "--quick", "--plant-step", "nan", "--out", "out", "--workers", "0"],
        must_name=("--plant-step", "nan"))
    add("experiment-settle-negative", "3.3",
        ["experiment", "--quick", "--settle", "-1", "--out", "out", "--workers", "0"],
        must_name=("--settle", "-1"))
    add("experiment-workers-huge", "3.2",
        ["experiment", "--quick", "--workers", "100000", "--out", "out"],
        must_name=("--workers", "100000"))
    add("ground-settle-huge", "3.2",
        ["ground", *MEMQ, "--no-auth", "--scenario-text", "{settle_s: 1.0e+9}",
         "--resume-wait", "0", "--realtime", "0"], absent=(), must_name=("settle_s",))
    add("experiment-workers-negative", "3.3",
        ["experiment", "--quick", "--workers", "-1", "--out", "out"],
        must_name=("--workers", "-1"))
    add("experiment-demos-text", "3.3",
        ["experiment", "--quick", "--demos", "x", "--out", "out", "--workers", "0"],
        must_name=("--demos", "x"))
    add("foresight-step-negative", "3.3", ["foresight", "--step", "-3", "--out", "out"],
        must_name=("--step", "-3"))
    add("foresight-step-huge", "3.3", ["foresight", "--step", "100000000", "--out", "out"],
        expect="ok", absent=(), note="one start, at t = 0")
    add("bench-repeat-zero", "3.3", ["bench", "--out", "out", "--repeat", "0", "--max-n", "100",
                                     "--ticks", "5", "--sim-duration", "0"],
        must_name=("--repeat", "0"))
    add("bench-ticks-zero", "3.3", ["bench", "--out", "out", "--ticks", "0", "--max-n", "100",
                                    "--repeat", "1", "--sim-duration", "0"],
        must_name=("--ticks", "0"))
    add("bench-sim-duration-nan", "3.3", ["bench", "--out", "out", "--sim-duration", "nan",
                                          "--max-n", "100", "--repeat", "1", "--ticks", "5"],
        must_name=("--sim-duration", "nan"))
    add("relay-bad-url", "3.3",
        ["link-relay", "--in-url", "bogus://", "--out-url", "memq://", "--duration", "0.1"],
        absent=(), must_name=("--in-url", "bogus://"))
    add("relay-link-int-key", "3.3",
        ["link-relay", "--in-url", "memq://a", "--out-url", "memq://b", "--duration", "0.1",
         "--link", "{1: 2}"], absent=(), must_name=("--link",))
    add("relay-link-list", "3.3",
        ["link-relay", "--in-url", "memq://a", "--out-url", "memq://b", "--duration", "0.1",
         "--link", "[1]"], absent=(), must_name=("--link",))

    # 3.4: ambiguity accepted silently
    add("scenario-duplicate-key", "3.4", [*SIM, "--scenario", "dup.yaml"],
        setup=write("dup.yaml", "Defaults:\n  arm: space_arm\n  arm: air_bearing_arm\n"),
        inputs=("dup.yaml",), must_name=("dup.yaml", "arm"))
    add("scenario-duplicate-nested-key", "3.4",
        [*SIM, "--scenario-text", "{haptic: {lasa_demo: 1, lasa_demo: 2}}"],
        must_name=("haptic.lasa_demo",))
    add("scenario-duplicate-entry", "3.4", [*SIM, "--scenario", "dup.yaml"],
        setup=write("dup.yaml", "Defaults: {}\nDefaults: {arm: space_arm}\n"),
        must_name=("Defaults",))
    add("relay-link-duplicate-key", "3.4",
        ["link-relay", "--in-url", "memq://a", "--out-url", "memq://b", "--duration", "0.1",
         "--link", "{delay_s: 0.1, delay_s: 0.2}"], absent=(), must_name=("--link", "delay_s"))
    add("smooth-limit-joint-twice", "3.4",
        ["smooth", "in.csv", "-o", "out/o.csv", "--acc-max", "a=1,a=2,b=1", "--jerk-max", "1"],
        must_name=("--acc-max", "a"))
    add("smooth-limit-unknown-joint", "3.4",
        ["smooth", "in.csv", "-o", "out/o.csv", "--acc-max", "a=1,c=2", "--jerk-max", "1"],
        must_name=("--acc-max", "c"))
    add("smooth-limit-underscore", "3.4",
        ["smooth", "in.csv", "-o", "out/o.csv", "--acc-max", "1_0", "--jerk-max", "1"],
        must_name=("--acc-max", "1_0"))
    add("smooth-limit-arabic-digit", "3.4",
        ["smooth", "in.csv", "-o", "out/o.csv", "--acc-max", "\u0661", "--jerk-max", "1"],
        must_name=("--acc-max",))
    add("smooth-joint-named-sent_t", "3.4", ["smooth", "r.csv", "-o", "out/o.csv", *LIMITS],
        setup=lambda folder: joint_csv(folder / "r.csv", names=("sent_t", "b")),
        must_name=("sent_t",))
    add("smooth-joint-named-t", "3.4", ["smooth", "r.csv", "-o", "out/o.csv", *LIMITS],
        setup=lambda folder: joint_csv(folder / "r.csv", names=("t", "b")),
        must_name=("'t'",))
    add("smooth-joint-named-padded", "3.4", ["smooth", "r.csv", "-o", "out/o.csv", *LIMITS],
        setup=lambda folder: joint_csv(folder / "r.csv", names=("a", " a")),
        must_name=("a",))
    add("smooth-cell-underscore", "3.4", ["smooth", "u.csv", "-o", "out/o.csv", *LIMITS],
        setup=write("u.csv", "t,a\n0,1_0e-3\n0.25,0\n0.5,0\n"), must_name=("1_0e-3", "line 2"))
    add("smooth-cell-arabic-digits", "3.4", ["smooth", "u.csv", "-o", "out/o.csv", *LIMITS],
        setup=write("u.csv", "t,a\n0,\u0661\u0662\n0.25,0\n0.5,0\n"), must_name=("line 2",))
    add("smooth-cell-fullwidth-digits", "3.4", ["smooth", "u.csv", "-o", "out/o.csv", *LIMITS],
        setup=write("u.csv", "t,a\n0,\uff11\n0.25,0\n0.5,0\n"), must_name=("line 2",))
    add("smooth-time-underscore", "3.4", ["smooth", "u.csv", "-o", "out/o.csv", *LIMITS],
        setup=write("u.csv", "t,a\n0,0\n0.2_5,0\n0.5,0\n"), must_name=("0.2_5", "line 3"))
    add("smooth-cell-nbsp", "3.4", ["smooth", "u.csv", "-o", "out/o.csv", *LIMITS],
        setup=write("u.csv", "t,a\n0,\u00a01\n0.25,0\n0.5,0\n"), must_name=("line 2",))
    add("haptic-csv-underscore", "3.4",
        [*SIM, "--scenario-text", "{haptic: {source: file, file: h.csv}}"],
        setup=write("h.csv", "t,x_m,y_m,phi_rad\n0,0.7,0,0\n0.01,0.7,0,1_0\n"),
        must_name=("1_0",))
    add("haptic-csv-pose-named-sent_t", "3.4",
        [*SIM, "--scenario-text", "{haptic: {source: file, file: h.csv}}"],
        setup=write("h.csv", "t,x_m,sent_t\n0,0.7,0\n0.01,0.7,0\n"), must_name=("h.csv",))
    add("sigma-store-joint-twice", "3.4",
        [*SMOOTH, "--operator", "bob", "--sigma-store", "s.json"],
        setup=write("s.json", '{"format": "telesmooth-operator-sigma/1", "operators": '
                              '{"bob": {"a": 1, "a": 2, "b": 1}}}'),
        inputs=("s.json",), must_name=("s.json", "a"))

    # 3.5: errors that name an internal name
    add("scenario-haptic-period-named", "3.5",
        [*SIM, "--scenario-text", "{haptic: {period_s: -100}}"],
        must_name=("haptic.period_s", "-100"))
    add("scenario-lasa-shape-named", "3.5",
        [*SIM, "--scenario-text", "{haptic: {lasa_shape: Sshap}}"],
        must_name=("haptic.lasa_shape", "Sshap"))
    add("scenario-synthetic-period-named", "3.5",
        [*SIM, "--scenario-text", "{haptic: {source: synthetic, period_s: -1}}"],
        must_name=("haptic.period_s", "-1"))
    add("scenario-mapping-scale-named", "3.5",
        [*SIM, "--scenario-text", "{haptic: {lasa_mapping: {scale_m_per_unit: -1}}}"],
        must_name=("haptic.lasa_mapping.scale_m_per_unit", "-1"))
    add("scenario-smoother-sigma-named", "3.5",
        [*SIM, "--scenario-text", "{smoother: {sigma: [1, 2]}}"],
        must_name=("smoother.sigma",))
    add("scenario-smoother-lag-named", "3.5",
        [*SIM, "--scenario-text", "{smoother: {lag: 5}}"],
        must_name=("smoother.lag", "5"))
    add("demo-shape-named", "3.5", ["demo", "--shape", "Sshap", "--out", "out"],
        must_name=("--shape", "Sshap"))
    add("smooth-sigma-named", "3.5", [*SMOOTH, "--sigma", "-1"], must_name=("--sigma", "-1"))
    add("smooth-r-named", "3.5", [*SMOOTH, "--r", "0"], must_name=("--r", "0"))
    add("smooth-vel-named", "3.5", [*SMOOTH, "--method", "online-hard", "--vel-max", "-1"],
        must_name=("--vel-max", "-1"))
    add("relay-link-field-named", "3.5",
        ["link-relay", "--in-url", "memq://a", "--out-url", "memq://b", "--duration", "0.1",
         "--link", "{delay_s: -1}"], absent=(), must_name=("--link", "delay_s", "-1"))

    # 3.6: key material
    add("key-hex-as-path", "3.6", ["onboard", *MEMQ, "--uplink-key", HEX_KEY, "--duration",
                                   "0.5", "--realtime", "0"], absent=(),
        forbid=(HEX_KEY, HEX_KEY[:16]), must_name=("--uplink-key",))
    add("key-group-readable", "3.6",
        ["onboard", *MEMQ, "--uplink-key", "g.key", "--duration", "0.5", "--realtime", "0"],
        setup=write("g.key", HEX_KEY + "\n", 0o640), absent=(), forbid=(HEX_KEY,),
        must_name=("g.key", "chmod 600"))
    add("key-world-writable", "3.6",
        ["ground", *MEMQ, "--uplink-key", "w.key", "--duration", "0.5", "--realtime", "0",
         "--resume-wait", "0"],
        setup=write("w.key", HEX_KEY + "\n", 0o602), absent=(), forbid=(HEX_KEY,),
        must_name=("w.key", "chmod 600"))
    add("key-short", "3.6", ["onboard", *MEMQ, "--uplink-key", "s.key", "--duration", "0.5"],
        setup=write("s.key", "abcd\n", 0o600), absent=(), forbid=("abcd",),
        must_name=("s.key",))
    add("key-not-hex", "3.6", ["onboard", *MEMQ, "--uplink-key", "n.key", "--duration", "0.5"],
        setup=write("n.key", "zz" + HEX_KEY[2:] + "\n", 0o600), absent=(),
        forbid=(HEX_KEY[2:18],), must_name=("n.key",))
    add("key-env-not-hex", "3.6", ["onboard", *MEMQ, "--duration", "0.5"],
        env={"TELESMOOTH_UPLINK_KEY": "zz" + HEX_KEY[2:]}, absent=(),
        forbid=(HEX_KEY[2:18],), must_name=("TELESMOOTH_UPLINK_KEY",))
    add("key-missing", "3.6", ["onboard", *MEMQ, "--uplink-key", "nope.key", "--duration",
                               "0.5"], absent=(), must_name=("nope.key",))
    add("key-is-dir", "3.6", ["onboard", *MEMQ, "--uplink-key", "dir", "--duration", "0.5"],
        absent=(), must_name=("dir",))
    add("key-symlink-to-0644", "3.6",
        ["onboard", *MEMQ, "--uplink-key", "l.key", "--duration", "0.5", "--realtime", "0"],
        setup=many(write("p.key", HEX_KEY + "\n", 0o644),
                   lambda folder: (folder / "l.key").symlink_to("p.key")),
        absent=(), forbid=(HEX_KEY,), must_name=("chmod 600",))
    return c


# --- running ----------------------------------------------------------------------------------

@dataclasses.dataclass
class Result:
    case: Case
    outcome: str
    status: object
    seconds: float
    max_rss_mb: float
    line: str


def _digest(path: Path):
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest() if path.is_file() else "missing"
    except OSError:
        return "unreadable"


def run_case(case: Case, main) -> Result:
    folder = Path(tempfile.mkdtemp(prefix=f"redteam-{case.id}-"))
    base_files(folder)
    if case.setup is not None:
        case.setup(folder)
    before = {name: _digest(folder / name) for name in case.inputs}
    stdout_path, stderr_path = folder.parent / f"{folder.name}.out", folder.parent / \
        f"{folder.name}.err"
    argv = [str(a) for a in case.argv]
    started = time.monotonic()
    pid = os.fork()
    if pid == 0:   # the child: limits, redirection, the command
        try:
            soft = MEMORY_LIMIT_BYTES + _mapped_bytes()
            resource.setrlimit(resource.RLIMIT_AS, (soft, soft))
            os.chdir(folder)
            os.environ["HOME"] = str(folder / "home")
            for name, value in case.env.items():
                os.environ[name] = value
            out = os.open(stdout_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
            err = os.open(stderr_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
            os.dup2(out, 1)
            os.dup2(err, 2)
            sys.stdout = io.TextIOWrapper(os.fdopen(1, "wb", 0), write_through=True)
            sys.stderr = io.TextIOWrapper(os.fdopen(2, "wb", 0), write_through=True)
            try:
                code = main(argv)
            except SystemExit as exit_:
                code = exit_.code if isinstance(exit_.code, int) else 1
            except BaseException:   # noqa: BLE001 - a traceback is what we look for
                import traceback

                traceback.print_exc()
                code = 99
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(code if isinstance(code, int) else 0)
        except BaseException:   # noqa: BLE001
            os._exit(98)
    deadline = started + case.time_limit_s
    status, rusage = None, None
    while True:
        waited, raw, rusage = os.wait4(pid, os.WNOHANG)
        if waited:
            status = raw
            break
        if time.monotonic() > deadline:
            os.kill(pid, signal.SIGKILL)
            _, status, rusage = os.wait4(pid, 0)
            status = "timeout"
            break
        time.sleep(0.05)
    seconds = time.monotonic() - started
    max_rss_mb = rusage.ru_maxrss / 1024 if rusage else 0.0
    stderr = stderr_path.read_text(errors="replace") if stderr_path.exists() else ""
    stdout = stdout_path.read_text(errors="replace") if stdout_path.exists() else ""
    lines = [line for line in stderr.splitlines() if line.strip()]
    last = lines[-1] if lines else ""
    if status == "timeout":
        outcome, code = "HANG", "timeout"
    elif os.WIFSIGNALED(status):
        outcome, code = "CRASH", f"signal {os.WTERMSIG(status)}"
    else:
        code = os.WEXITSTATUS(status)
        outcome = _judge(case, code, stderr, stdout, lines, last, folder, before)
    return Result(case, outcome, code, seconds, max_rss_mb, last[:MAX_LINE + 40])


def _judge(case, code, stderr, stdout, lines, last, folder, before) -> str:
    if "Traceback" in stderr or code in (98, 99):
        return "TRACEBACK"
    for secret in case.forbid:
        if secret in stderr or secret in stdout:
            return "LEAK"
    for name in case.inputs:
        if _digest(folder / name) != before[name]:
            return "CHANGED"
    if case.expect == "ok":
        return "ok" if code == 0 else "STATUS"
    for name in case.absent:
        path = folder / name
        if path.exists() or path.is_symlink():
            return "WROTE"
    if code != 2:
        return "STATUS"
    error_lines = [line for line in lines if "error" in line.lower()]
    if len(error_lines) != 1 or len(last) > MAX_LINE or "error" not in last.lower():
        return "LONG"
    if any(word.lower() not in last.lower() for word in case.must_name):
        return "UNNAMED"
    return "ok"


def _mapped_bytes() -> int:
    with open("/proc/self/statm") as handle:
        return int(handle.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", default=None, help="run the cases whose id starts so")
    parser.add_argument("--cls", default=None, help="run the cases of one class (e.g. 3.2)")
    parser.add_argument("--markdown", action="store_true", help="print a Markdown table")
    args = parser.parse_args(argv)
    os.environ.setdefault("MPLBACKEND", "Agg")
    import telesmooth.diagrams.simulation  # noqa: F401 - imported once, before the forks
    import telesmooth.scripts.simulate_report  # noqa: F401
    from telesmooth.scripts.cli import main as cli_main

    selected = [c for c in cases()
                if (args.only is None or c.id.startswith(args.only))
                and (args.cls is None or c.cls == args.cls)]
    results = []
    for case in selected:
        result = run_case(case, cli_main)
        results.append(result)
        print(f"{result.outcome:9s} {case.cls:4s} {case.id:38s} {str(result.status):8s} "
              f"{result.seconds:6.1f} s {result.max_rss_mb:7.0f} MB  {result.line[:150]}",
              file=sys.stderr, flush=True)
    bad = [r for r in results if r.outcome != "ok"]
    print(f"\n{len(results)} cases in {len({r.case.cls for r in results})} classes; "
          f"{len(bad)} not ok", file=sys.stderr)
    if args.markdown:
        print("| class | case | command | outcome | status | s | MB | last line |")
        print("|---|---|---|---|---|---:|---:|---|")
        for r in results:
            command = " ".join(r.case.argv)
            command = command if len(command) <= 70 else command[:67] + "…"
            line = r.line.replace("|", "\\|")
            print(f"| {r.case.cls} | {r.case.id} | `{command.replace('|', '/')}` | {r.outcome} "
                  f"| {r.status} | {r.seconds:.1f} | {r.max_rss_mb:.0f} | {line[:200]} |")
    return 0 if not bad else 1


if __name__ == "__main__":
    sys.exit(main())
