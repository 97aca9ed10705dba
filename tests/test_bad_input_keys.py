"""Bad input, class 6: key material is never printed, and a key file others can access is
refused (as ssh refuses such a private key), with the ``chmod`` that fixes it."""

import os

import pytest
from bad_input_helpers import assert_one_line_error, run, snapshot

KEY_HEX = "8f" * 32


@pytest.fixture
def folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("TELESMOOTH_UPLINK_KEY", raising=False)
    return tmp_path


def _key(path, text, mode):
    path.write_text(text)
    os.chmod(path, mode)


@pytest.mark.parametrize("command", ["ground", "onboard"])
def test_a_hex_key_given_as_the_key_file_is_not_echoed(folder, capsys, command):
    status, stdout, stderr = run(capsys, command, "--lcm-url", "memq://", "--uplink-key",
                                 KEY_HEX, "--duration", "1")
    line = assert_one_line_error(status, stdout, stderr, command, "--uplink-key",
                                 "64-character hex string", "not shown")
    assert KEY_HEX[:8] not in stdout + stderr and KEY_HEX[-8:] not in line


@pytest.mark.parametrize("mode", [0o640, 0o604, 0o620, 0o602, 0o644, 0o666])
def test_a_key_file_others_can_access_is_refused_with_the_chmod(folder, capsys, mode):
    _key(folder / "uplink.key", KEY_HEX + "\n", mode)
    before = snapshot(folder)
    status, stdout, stderr = run(capsys, "onboard", "--lcm-url", "memq://", "--uplink-key",
                                 "uplink.key", "--duration", "0.2", "--realtime", "0")
    assert_one_line_error(status, stdout, stderr, "onboard", "--uplink-key",
                          f"has mode {mode:#o}", "chmod 600 uplink.key")
    assert KEY_HEX[:8] not in stderr
    assert snapshot(folder) == before
    assert oct(os.stat(folder / "uplink.key").st_mode & 0o777) == oct(mode)   # not "fixed"


@pytest.mark.parametrize("text", ["zz" + KEY_HEX[2:], KEY_HEX[:30], "", KEY_HEX + "\x00"])
def test_bad_key_contents_are_described_never_shown(folder, capsys, text):
    _key(folder / "uplink.key", text, 0o600)
    status, stdout, stderr = run(capsys, "onboard", "--lcm-url", "memq://", "--uplink-key",
                                 "uplink.key", "--duration", "0.2")
    assert_one_line_error(status, stdout, stderr, "onboard", "uplink key file 'uplink.key'")
    assert (text[2:12] or "\x00") not in stderr


def test_a_bad_key_in_the_environment_is_described_never_shown(folder, capsys, monkeypatch):
    monkeypatch.setenv("TELESMOOTH_UPLINK_KEY", "zz" + KEY_HEX[2:])
    status, stdout, stderr = run(capsys, "onboard", "--lcm-url", "memq://", "--duration", "0.2")
    assert_one_line_error(status, stdout, stderr, "onboard", "TELESMOOTH_UPLINK_KEY",
                          "not a hex string")
    assert KEY_HEX[2:18] not in stderr


def test_a_private_key_file_works(folder, capsys):
    _key(folder / "uplink.key", KEY_HEX + "\n", 0o600)
    status, _, stderr = run(capsys, "onboard", "--lcm-url", "memq://", "--uplink-key",
                            "uplink.key", "--duration", "0.3", "--realtime", "0")
    assert status == 0, stderr
    assert KEY_HEX[:8] not in stderr
