"""Bad input, class 1: no output destroys an input, and a failure writes nothing.

The mechanism (telesmooth.atomic_files): every writer writes a temporary file beside its
destination and renames it into place; every command declares its outputs up front in an
``Outputs``, which refuses an output that is an input (or another output, a folder, a file in
a folder's place) before any work, and puts the staged outputs in place only on success.
"""

import os
import stat

import pytest
from bad_input_helpers import assert_one_line_error, run, snapshot, write_trajectory

from telesmooth.atomic_files import OutputPathError, Outputs, atomic_write, write_text

LIMITS = ["--acc-max", "0.05", "--jerk-max", "0.1"]


@pytest.fixture
def folder(tmp_path, monkeypatch):
    """A scratch folder (the working directory) with an input trajectory ``in.csv``."""
    monkeypatch.chdir(tmp_path)
    write_trajectory(tmp_path)
    (tmp_path / "dir").mkdir()
    (tmp_path / "link.csv").symlink_to("in.csv")
    return tmp_path


# --- the command line: one case per way an output can hit an input or fail ---

SMOOTH_CASES = {
    "-o is the input": (["-o", "in.csv"], ("-o = 'in.csv'", "is the input file")),
    "-o is a link to the input": (["-o", "link.csv"], ("-o = 'link.csv'", "is the input")),
    "-o names the input by another path": (["-o", "dir/../in.csv"], ("is the input",)),
    "--metrics is the input": (["-o", "out.csv", "--metrics", "in.csv"],
                               ("--metrics = 'in.csv'", "is the input")),
    "--sigma-store is the input": (["-o", "out.csv", "--operator", "bob", "--sigma-store",
                                    "in.csv"], ("--sigma-store = 'in.csv'", "is the input")),
    "--metrics is -o": (["-o", "out.csv", "--metrics", "out.csv"],
                        ("--metrics = 'out.csv'", "is also the output of -o")),
    "-o is a folder": (["-o", "dir"], ("-o = 'dir' is a folder",)),
    "-o inside a file": (["-o", "in.csv/out.csv"], ("'in.csv' is a file, not a folder",)),
    "--metrics is a folder": (["-o", "out.csv", "--metrics", "dir"],
                              ("--metrics = 'dir' is a folder",)),
    "--sigma-store is a folder": (["-o", "out.csv", "--operator", "bob", "--sigma-store",
                                   "dir"], ("--sigma-store = 'dir' is a folder",)),
}


@pytest.mark.parametrize("case", SMOOTH_CASES)
def test_smooth_never_overwrites_an_input_and_writes_nothing_on_error(folder, capsys, case):
    args, words = SMOOTH_CASES[case]
    before = snapshot(folder)
    status, stdout, stderr = run(capsys, "smooth", "in.csv", *args, *LIMITS)
    assert_one_line_error(status, stdout, stderr, "smooth", *words)
    assert snapshot(folder) == before     # input bytes unchanged, nothing added (no temp file)


def test_a_failing_metrics_write_leaves_no_output_csv(folder, capsys, monkeypatch):
    """The issue's case: -o was written, then --metrics failed. Now both are staged and put in
    place together, so a failure in the second leaves neither."""
    import telesmooth.atomic_files as atomic_files

    real = atomic_files.write_text

    def failing(path, text, **kwargs):
        if "m.json" in str(path):
            raise OSError(28, "No space left on device", str(path))
        return real(path, text, **kwargs)

    monkeypatch.setattr(atomic_files, "write_text", failing)
    before = snapshot(folder)
    status, stdout, stderr = run(capsys, "smooth", "in.csv", "-o", "out/o.csv", "--metrics",
                                 "out/m.json", *LIMITS)
    assert_one_line_error(status, stdout, stderr, "smooth", "No space left on device")
    assert snapshot(folder) == before     # no out/o.csv, not even the out/ folder


def test_a_successful_run_replaces_an_old_output_and_keeps_the_input(folder, capsys):
    (folder / "out.csv").write_text("old\n")
    os.chmod(folder / "out.csv", 0o640)
    status, _, stderr = run(capsys, "smooth", "in.csv", "-o", "out.csv", "--metrics",
                            "sub/m.json", *LIMITS)
    assert status == 0, stderr
    assert (folder / "out.csv").read_text().startswith("t,a,b,sent_t\n")
    assert stat.S_IMODE((folder / "out.csv").stat().st_mode) == 0o640   # mode kept
    assert (folder / "sub" / "m.json").is_file()
    assert sorted(p.name for p in folder.iterdir()) == ["dir", "in.csv", "link.csv", "out.csv",
                                                        "sub"]   # no temporary file left


def test_smooth_to_dev_null_writes_in_place(folder, capsys):
    status, _, stderr = run(capsys, "smooth", "in.csv", "-o", "/dev/null", *LIMITS)
    assert status == 0, stderr
    assert stat.S_ISCHR(os.stat("/dev/null").st_mode)     # still the device, not a file


@pytest.mark.parametrize("argv, words", [
    (["demo", "--out", "in.csv"], ("--out = 'in.csv' is a file, not a folder",)),
    (["demo", "--out", "in.csv/sub"], ("'in.csv' is a file, not a folder",)),
    (["simulate", "--scenario", "scn.yaml", "--out", "scn.yaml"],
     ("--out = 'scn.yaml' is a file",)),
    (["bench", "--out", "in.csv", "--max-n", "100"], ("--out = 'in.csv' is a file",)),
    (["ground", "--lcm-url", "memq://", "--no-auth", "--out", "in.csv", "--duration", "1"],
     ("--out = 'in.csv' is a file",)),
    (["link-relay", "--in-url", "memq://a", "--out-url", "memq://b", "--duration", "0.1",
      "--report", "dir"], ("--report = 'dir' is a folder",)),
])
def test_report_folders_and_files_in_the_way_are_refused_before_any_work(folder, capsys, argv,
                                                                         words):
    (folder / "scn.yaml").write_text("Defaults: {}\n")
    before = snapshot(folder)
    status, stdout, stderr = run(capsys, *argv)
    assert_one_line_error(status, stdout, stderr, argv[0], *words)
    assert snapshot(folder) == before


def test_a_report_file_that_would_replace_an_input_writes_nothing(folder, capsys):
    """An input inside --out is fine unless the report writes a file of the same name; then
    nothing of the report is put in place and the input keeps its bytes."""
    out = folder / "out"
    out.mkdir()
    (out / "telemetry.csv").write_text("t,x_m,y_m,phi_rad\n0,0.7,0,0\n0.01,0.7,0,0\n")
    (out / "keep.txt").write_text("mine")
    before = snapshot(folder)
    status, stdout, stderr = run(
        capsys, "simulate", "--scenario-text",
        "{haptic: {source: file, file: out/telemetry.csv}}", "--out", "out",
        "--duration", "2")
    assert_one_line_error(status, stdout, stderr, "simulate", "--out = 'out'",
                          "'telemetry.csv' would overwrite the input haptic.file")
    assert snapshot(folder) == before


# --- the mechanism ---

def test_atomic_write_keeps_the_old_file_when_the_writer_fails(tmp_path):
    path = tmp_path / "data.csv"
    path.write_text("old content\n")
    with pytest.raises(RuntimeError, match="half-way"):
        with atomic_write(path) as handle:
            handle.write("new, half-")
            raise RuntimeError("failed half-way")
    assert path.read_text() == "old content\n"
    assert [p.name for p in tmp_path.iterdir()] == ["data.csv"]


def test_atomic_write_follows_a_symbolic_link(tmp_path):
    (tmp_path / "real.txt").write_text("old")
    (tmp_path / "alias.txt").symlink_to("real.txt")
    write_text(tmp_path / "alias.txt", "new")
    assert (tmp_path / "alias.txt").is_symlink()
    assert (tmp_path / "real.txt").read_text() == "new"


def test_outputs_abort_removes_what_it_staged_and_the_folders_it_made(tmp_path):
    outputs = Outputs()
    staged = outputs.file("-o", tmp_path / "a" / "b" / "out.csv")
    folder = outputs.folder("--out", tmp_path / "c" / "report")
    staged.write_text("x")
    (folder / "report.md").write_text("y")
    outputs.abort()
    assert list(tmp_path.iterdir()) == []


def test_outputs_commit_puts_a_report_into_an_existing_folder_and_keeps_other_files(tmp_path):
    report = tmp_path / "report"
    report.mkdir()
    (report / "notes.txt").write_text("mine")
    (report / "report.md").write_text("old")
    with Outputs() as outputs:
        staged = outputs.folder("--out", report)
        (staged / "report.md").write_text("new")
        (staged / "figures").mkdir()
        (staged / "figures" / "a.png").write_bytes(b"png")
    assert (report / "notes.txt").read_text() == "mine"
    assert (report / "report.md").read_text() == "new"
    assert (report / "figures" / "a.png").read_bytes() == b"png"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report"]


def test_outputs_refuse_an_output_declared_after_as_an_input(tmp_path):
    (tmp_path / "in.csv").write_text("keep")
    outputs = Outputs()
    outputs.file("-o", tmp_path / "in.csv")
    with pytest.raises(OutputPathError, match="is the input haptic.file"):
        outputs.add_input("haptic.file", tmp_path / "in.csv")
    outputs.abort()
    assert (tmp_path / "in.csv").read_text() == "keep"
    assert [p.name for p in tmp_path.iterdir()] == ["in.csv"]
