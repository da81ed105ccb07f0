"""A child of `offload.Offload`: ``python -m normbox_lab.analyze.offload_worker MODULE:FUNCTION``
reads payload pickles on stdin until its end, calls FUNCTION(payload) for each and writes
("ok", result) or ("error", message) pickles on stdout.  Anything else the job prints goes to
stderr, so stdout carries only the pickles."""

from __future__ import annotations

import importlib
import os
import pickle
import sys


def main(argv: list[str]) -> int:
    out = os.fdopen(os.dup(sys.stdout.fileno()), "wb")
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())
    module, _, name = argv[0].partition(":")
    work = vars(importlib.import_module(module))[name]   # imported before the first job
    inp = sys.stdin.buffer
    while True:
        try:
            payload = pickle.load(inp)
        except EOFError:
            return 0
        try:
            reply: tuple[str, object] = ("ok", work(payload))
        except Exception as exc:  # noqa: BLE001 - the parent does the job again and raises it
            reply = ("error", f"{type(exc).__name__}: {exc}")
        pickle.dump(reply, out)
        out.flush()


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
