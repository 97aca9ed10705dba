"""The live console's command line: where the page listens, bad options, a short 6-DOF run.

* Meshcat listens on 127.0.0.1 by default (checked on the socket table); another interface
  needs --host and prints a warning (checked without listening there: tests bind 127.0.0.1
  only).
* A port in use, a port out of range, a bad duration, and a scenario key the console does
  not read are each one error line, exit 2, nothing written.
* `teleop` on the 6-DOF arm runs and writes its session (the planar arm is covered by
  tests/test_teleop.py and the live tests).
"""

import socket
from pathlib import Path

import pytest
from bad_input_helpers import assert_one_line_error, run

from telesmooth.scripts.teleop import exposure_warning, open_meshcat


def _listening_addresses(port: int) -> set:
    """The local addresses of the TCP sockets listening on ``port`` (from /proc/net/tcp)."""
    found = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        path = Path(table)
        if not path.exists():
            continue
        for line in path.read_text().splitlines()[1:]:
            fields = line.split()
            address, state = fields[1], fields[3]
            host, port_hex = address.rsplit(":", 1)
            if state == "0A" and int(port_hex, 16) == port:    # 0A: LISTEN
                found.add(host)
    return found


def test_the_page_listens_on_this_machine_only_by_default():
    meshcat = open_meshcat("127.0.0.1", None)
    port = meshcat.port()
    # 0100007F is 127.0.0.1 in /proc's byte order; 00000000 would be every interface.
    assert _listening_addresses(port) == {"0100007F"}, _listening_addresses(port)


@pytest.mark.parametrize("host", ["0.0.0.0", "192.168.1.20", "::", "robot-console.example"])
def test_another_interface_is_said_out_loud(host):
    warning = exposure_warning(host)
    assert warning is not None
    assert f"--host {host}" in warning and "anyone who reaches it can drive the robot" in warning


@pytest.mark.parametrize("host", ["127.0.0.1", "localhost", "127.0.0.2", "::1"])
def test_this_machine_is_not_warned_about(host):
    assert exposure_warning(host) is None


def test_the_warning_is_printed_before_the_page_opens(capsys, monkeypatch):
    """Without listening anywhere but here (tests bind 127.0.0.1 only): Meshcat is replaced
    by a recorder of the parameters it was given."""
    import pydrake.geometry

    given = []
    monkeypatch.setattr(pydrake.geometry, "Meshcat", lambda params: given.append(params))
    open_meshcat("0.0.0.0", 7123, "operator")
    err = capsys.readouterr().err
    assert err.startswith("operator: warning: --host 0.0.0.0"), err
    assert [(p.host, p.port) for p in given] == [("0.0.0.0", 7123)]


def test_a_port_in_use_is_one_line(capsys, tmp_path):
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        status, out, err = run(capsys, "teleop", "--port", port, "--duration", "1", "--out",
                               tmp_path / "session")
    assert_one_line_error(status, out, err, "teleop", f"--port = {port}", "in use")
    assert not (tmp_path / "session").exists()


@pytest.mark.parametrize("argv, words", [
    (["teleop", "--port", "70000"], ["--port = 70000"]),
    (["teleop", "--duration", "-1"], ["--duration = -1"]),
    (["teleop", "--duration", "nan"], ["--duration = nan"]),
    (["operator", "--lcm-url", "tcpq://x"], ["--lcm-url", "tcpq://x"]),
    (["teleop", "--scenario-text", "{haptic: {lasa_shape: Sshape}}"],
     ["haptic.lasa_shape", "console"]),
])
def test_bad_options_are_one_line(capsys, tmp_path, argv, words):
    status, out, err = run(capsys, *argv, "--out", tmp_path / "session")
    assert_one_line_error(status, out, err, argv[0], *words)
    assert not (tmp_path / "session").exists()


def test_the_six_dof_arm_runs_live(tmp_path, capsys):
    status, out, err = run(capsys, "teleop", "--scenario-text", "{arm: space_arm}",
                           "--duration", "2", "--out", tmp_path / "session")
    assert status == 0, err
    assert out.startswith("operator console: http://127.0.0.1:")
    header = (tmp_path / "session" / "operator.csv").read_text().splitlines()[0]
    assert header == "t,x_m,y_m,z_m,roll_rad,pitch_rad,yaw_rad,enable"
    assert "# telesmooth teleop" in (tmp_path / "session" / "report.md").read_text()


def test_the_scripted_operator_drives_only_a_page_on_this_machine(capsys):
    # Catches: a scripted operator pointed at another machine's console (it would drive
    # someone's robot over the network).
    from telesmooth.scripts.browser_operator import main as browser_operator

    with pytest.raises(SystemExit) as raised:
        browser_operator(["--url", "http://10.0.0.7:7000/"])
    assert raised.value.code == 2
    assert "--url = 'http://10.0.0.7:7000/': only a page on this machine" in (
        capsys.readouterr().err)
