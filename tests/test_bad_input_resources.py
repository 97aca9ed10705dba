"""Bad input, class 2: no input makes a reader use unbounded memory or time.

The mechanism (telesmooth.user_input): every reader takes its bytes through
``read_file_bytes``, which refuses anything but a regular file before reading (``/dev/zero``,
``/dev/urandom``, a FIFO that would block) and bounds the size; each format then bounds what
it builds (CSV rows, columns and line length; YAML depth, aliases, expanded nodes and scalar
length, checked on the event stream before anything is built; JSON depth; NPZ members and the
sizes their zip entries and .npy headers declare, before decompressing); the fixed-lag cost
is bounded through ``--lag``. Errors quote the value cut short.
"""

import io
import json
import os
import tracemalloc
import zipfile

import numpy as np
import pytest
from bad_input_helpers import assert_one_line_error, deadline, run, snapshot, write_trajectory
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from telesmooth.datasets.haptic_recording import read_haptic_csv, read_haptic_npz
from telesmooth.link.auth import load_key
from telesmooth.smoothing.sigma_store import stored_operators
from telesmooth.smoothing.trajectory_io import read_joint_csv
from telesmooth.typed_yaml import load_yaml_text
from telesmooth.user_input import MAX_YAML_NODES, MAX_YAML_SCALAR_CHARS

LIMITS = ["--acc-max", "0.05", "--jerk-max", "0.1"]


@pytest.fixture
def folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    write_trajectory(tmp_path)
    os.mkfifo(tmp_path / "fifo")
    with open(tmp_path / "sparse", "wb") as handle:
        handle.truncate(1 << 30)           # 1 GiB of zeros that takes no disk space
    os.chmod(tmp_path / "sparse", 0o600)  # (a key file must be private to be read at all)
    return tmp_path


def billion_laughs(levels: int) -> str:
    lines = ['a0: &a0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    lines += [f"a{k}: &a{k} [{', '.join([f'*a{k - 1}'] * 10)}]" for k in range(1, levels + 1)]
    return "\n".join(lines) + f"\nDefaults: {{haptic: {{lasa_mapping: *a{levels}}}}}\n"


# --- every entry point that reads a file, given an endless or enormous one ---

ENDLESS = ["/dev/zero", "/dev/urandom", "fifo", "sparse"]


def _reader_commands(source):
    """(command, argv, what the line must name) for each reader, reading ``source``."""
    return [
        ("smooth", ["smooth", source, "-o", "out/o.csv", *LIMITS], source),
        ("smooth", ["smooth", "in.csv", "-o", "out/o.csv", *LIMITS, "--operator", "bob",
                    "--sigma-store", source], "--sigma-store"),
        ("simulate", ["simulate", "--scenario", source, "--out", "out"], "--scenario"),
        ("simulate", ["simulate", "--scenario-text",
                      f"{{haptic: {{source: file, file: {source}}}}}", "--out", "out"],
         "haptic.file"),
        ("simulate", ["simulate", "--scenario-text",
                      f"{{haptic: {{source: file, file: {source}.npz}}}}", "--out", "out"],
         "haptic.file"),
        ("onboard", ["onboard", "--lcm-url", "memq://", "--uplink-key", source, "--duration",
                     "1"], "--uplink-key"),
    ]


@pytest.mark.parametrize("source", ENDLESS)
@pytest.mark.parametrize("index", range(6))
def test_an_endless_or_enormous_file_is_refused_before_reading(folder, capsys, source, index):
    if index == 4 and source.startswith("/dev"):
        pytest.skip("no .npz twin of a device")
    if index == 4:
        os.rename(folder / source, folder / f"{source}.npz")
    command, argv, name = _reader_commands(source)[index]
    before = snapshot(folder)
    with deadline(60):
        status, stdout, stderr = run(capsys, *argv)
    line = assert_one_line_error(status, stdout, stderr, command, name)
    assert any(word in line for word in ("character device", "FIFO", "the limit is"))
    assert snapshot(folder) == before


def test_csv_rows_beyond_the_bound_are_refused_as_they_are_read(folder, monkeypatch):
    import telesmooth.smoothing.trajectory_io as trajectory_io

    monkeypatch.setattr(trajectory_io, "MAX_CSV_ROWS", 50)
    (folder / "long.csv").write_text("t,a\n" + "".join(f"{k},0\n" for k in range(51)))
    with pytest.raises(ValueError, match=r"more than 50 data rows \(line 52\)"):
        read_joint_csv(folder / "long.csv")


@pytest.mark.parametrize("text, words", [
    ("t," + ",".join(f"j{k}" for k in range(1001)) + "\n", "1002 cells; the limit is 1000"),
    ("t,a\n0," + "1" * (1 << 20) + "\n", "line 2 is longer than 1048576 characters"),
])
def test_csv_columns_and_line_length_are_bounded(folder, text, words):
    (folder / "wide.csv").write_text(text)
    with pytest.raises(ValueError, match=words):
        read_joint_csv(folder / "wide.csv")


YAML_CASES = {
    "billion laughs": (billion_laughs(9), f"more than {MAX_YAML_NODES} values"),
    "deep nesting": ("Defaults: " + "[" * 100_000 + "]" * 100_000 + "\n",
                     "nesting deeper than 32 levels at line 1"),
    "long string": ("Defaults: {arm: " + "x" * (MAX_YAML_SCALAR_CHARS + 1) + "}\n",
                    "longer than 4096 characters"),
    "megabyte file": ("Defaults: {arm: " + "x" * (2 << 20) + "}\n", "is 2.0 MiB; the limit is"),
    "many aliases": ("a: &a 1\nDefaults: {settle_s: [" + ", ".join(["*a"] * 1001) + "]}\n",
                     "more than 1000 aliases"),
}


@pytest.mark.parametrize("case", YAML_CASES)
def test_scenario_yaml_bombs_are_refused_on_the_event_stream(folder, capsys, case):
    text, words = YAML_CASES[case]
    (folder / "s.yaml").write_text(text)
    before = snapshot(folder)
    tracemalloc.start()
    try:
        status, stdout, stderr = run(capsys, "simulate", "--scenario", "s.yaml", "--out", "out")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    line = assert_one_line_error(status, stdout, stderr, "simulate", "--scenario = 's.yaml'",
                                 words)
    assert "x" * 100 not in line                      # values are quoted cut short
    assert peak < 64 * len(text) + (16 << 20), peak    # no expansion in memory
    assert snapshot(folder) == before


def test_scenario_text_and_link_options_have_the_same_bounds(capsys):
    status, stdout, stderr = run(capsys, "simulate", "--scenario-text", billion_laughs(7),
                                 "--out", "out")
    assert_one_line_error(status, stdout, stderr, "simulate", "--scenario-text",
                          "more than 100000 values")
    status, stdout, stderr = run(capsys, "link-relay", "--in-url", "memq://a", "--out-url",
                                 "memq://b", "--duration", "0.1",
                                 "--link", "[" * 1000 + "]" * 1000)
    assert_one_line_error(status, stdout, stderr, "link-relay", "--link: nesting deeper")


def _npz(arrays) -> bytes:
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **arrays)
    return buffer.getvalue()


def test_npz_members_are_bounded_before_decompression(tmp_path, monkeypatch):
    import telesmooth.datasets.haptic_recording as haptic_recording

    path = tmp_path / "big.npz"
    path.write_bytes(_npz({"t_s": np.zeros(100_000), "pose": np.zeros((2, 3)),
                           "pose_names": np.array(["x_m", "y_m", "phi_rad"])}))
    monkeypatch.setattr(haptic_recording, "MAX_NPZ_ARRAY_BYTES", 1 << 16)
    with pytest.raises(ValueError, match=r"member 't_s.npy' decompresses to 781.4 KiB; the "
                                         r"limit is 64 KiB"):
        read_haptic_npz(path)


def test_npz_header_claiming_a_huge_array_is_refused_without_allocating(tmp_path):
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(
        header, {"descr": "<f8", "fortran_order": False, "shape": (10**12,)})
    path = tmp_path / "lie.npz"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as archive:
        archive.writestr("t_s.npy", header.getvalue() + bytes(64))
    tracemalloc.start()
    try:
        with pytest.raises(ValueError, match=r"array 't_s.npy' claims shape \(1000000000000,\)"):
            read_haptic_npz(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 8 << 20


def test_npz_with_too_many_members_is_refused(tmp_path):
    path = tmp_path / "many.npz"
    path.write_bytes(_npz({f"m{k}": np.zeros(1) for k in range(17)}))
    with pytest.raises(ValueError, match="17 archive members; a haptic NPZ holds at most 16"):
        read_haptic_npz(path)


@pytest.mark.parametrize("argv, words", [
    (["--method", "bmfls", "--lag", "10000"], "--lag = 10000 must be at most 1000 samples"),
    (["--lag", "100000000"], "--lag = 100000000 must be at most 1000"),
    (["--method", "bmfls", "--lag", "500"], "--lag = 500 samples is longer than the recording "
                                            "(40 samples)"),
])
def test_a_lag_far_beyond_the_recording_is_refused_at_once(folder, capsys, argv, words):
    before = snapshot(folder)
    with deadline(30):
        status, stdout, stderr = run(capsys, "smooth", "in.csv", "-o", "o.csv", *LIMITS, *argv)
    assert_one_line_error(status, stdout, stderr, "smooth", words)
    assert snapshot(folder) == before


def test_a_deeply_nested_sigma_store_is_one_line(folder, capsys):
    (folder / "s.json").write_text("[" * 200_000 + "]" * 200_000)
    status, stdout, stderr = run(capsys, "smooth", "in.csv", "-o", "o.csv", *LIMITS,
                                 "--operator", "bob", "--sigma-store", "s.json")
    assert_one_line_error(status, stdout, stderr, "smooth", "--sigma-store",
                          "nested too deeply")


# --- properties: any bytes, bounded memory, a result or a ValueError ---

def _fuzz(examples):
    return settings(derandomize=True, database=None, deadline=None, max_examples=examples,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                           HealthCheck.function_scoped_fixture])


def _peak_of(reader, path):
    """(peak traced bytes, outcome) of ``reader(path)``; only ValueError may escape it."""
    tracemalloc.start()
    try:
        with deadline(60):
            try:
                reader(path)
                outcome = "read"
            except ValueError:
                outcome = "refused"
        return tracemalloc.get_traced_memory()[1], outcome
    finally:
        tracemalloc.stop()


def _load_scenario_yaml(path):
    return load_yaml_text(path.read_text(errors="replace"), source="fuzz")


def _sigma_store(path):
    return stored_operators(path)


READERS = {"joint csv": read_joint_csv, "haptic csv": read_haptic_csv,
           "haptic npz": read_haptic_npz, "yaml": _load_scenario_yaml,
           "sigma store": _sigma_store, "key file": load_key}

PREFIXES = {"joint csv": [b"t,a\n0,1\n", b"t,a,b\r\n"], "haptic csv": [b"t,x_m,y_m,phi_rad\n"],
            "haptic npz": [_npz({"t_s": np.arange(3.0)})[:40], b"PK\x03\x04"],
            "yaml": [b"a: &a [1, 2]\nb: [*a, *a]\n", b"{"],
            "sigma store": [b'{"format": "telesmooth-operator-sigma/1", "operators": {'],
            "key file": [b"8f" * 16]}


@pytest.mark.parametrize("name", READERS)
@_fuzz(30)
@given(data=st.data())
def test_every_reader_on_any_bytes_returns_or_refuses_within_bounded_memory(tmp_path, name,
                                                                             data):
    prefix = data.draw(st.sampled_from([b""] + PREFIXES[name]))
    body = data.draw(st.one_of(
        st.binary(max_size=2000),
        st.text(st.sampled_from(list("0123456789.,-+e&*[]{}:\n\r\"\t nai_")), max_size=2000)
        .map(str.encode),
        st.integers(1, 4000).map(lambda n: b"[" * n),
    ))
    path = tmp_path / "fuzz"
    path.write_bytes(prefix + body)
    os.chmod(path, 0o600)
    peak, _ = _peak_of(READERS[name], path)
    assert peak < 200 * len(prefix + body) + (4 << 20), (name, peak, len(prefix + body))


@pytest.mark.parametrize("levels", [3, 5, 7, 9])
def test_yaml_memory_does_not_grow_with_the_alias_expansion(tmp_path, levels):
    path = tmp_path / "laughs.yaml"
    path.write_text(billion_laughs(levels))
    peak, outcome = _peak_of(_load_scenario_yaml, path)
    assert outcome == ("read" if 10 ** (levels + 1) <= MAX_YAML_NODES else "refused")
    assert peak < 4 << 20


def test_json_sigma_store_bounds(tmp_path):
    path = tmp_path / "s.json"
    deep = {"format": "telesmooth-operator-sigma/1", "operators": {"bob": {"a": 1.0}}}
    for _ in range(20):
        deep = {"format": "telesmooth-operator-sigma/1", "operators": {"bob": {"a": deep}}}
    path.write_text(json.dumps(deep))
    with pytest.raises(ValueError, match="nested deeper than 16 levels"):
        stored_operators(path)
