"""`sim serve --option K=V` reaches the emulator (here: a CS-1000A with 1/20 of its timing)."""

import socket
import subprocess
import sys

from normbox_lab.cli import main


def test_option_must_be_k_equals_v(capsys):
    assert main(["sim", "serve", "cs1000a", "--tcp", "127.0.0.1:0", "--option", "noise"]) == 2
    assert "K=V" in capsys.readouterr().err


def test_options_reach_the_emulator_which_refuses_bad_ones(capsys):
    assert main(["sim", "serve", "cs1000a", "--tcp", "127.0.0.1:0",
                 "--option", "noise=maybe"]) == 2
    assert "noise must be on or off" in capsys.readouterr().err
    assert main(["sim", "serve", "cs1000a", "--pty", "--option", "bogus=1"]) == 2
    assert "bogus" in capsys.readouterr().err


def test_served_emulator_takes_options():
    proc = subprocess.Popen([sys.executable, "-m", "normbox_lab", "sim", "serve", "cs1000a",
                             "--tcp", "127.0.0.1:0", "--option", "time_factor=0.05",
                             "--option", "noise=off"], stdout=subprocess.PIPE, text=True)
    try:
        first = proc.stdout.readline().strip()
        assert first.startswith("tcp: 127.0.0.1:")
        port = int(first.rsplit(":", 1)[1])
        with socket.create_connection(("127.0.0.1", port), timeout=10) as conn:
            conn.sendall(b"RMT,1\n")
            assert conn.makefile("rb").readline() == b"OK\n"
    finally:
        proc.terminate()
        proc.wait(timeout=10)
    assert proc.returncode == 0
