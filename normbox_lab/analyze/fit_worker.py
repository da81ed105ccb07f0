"""A child of `fit.fit_materials`: reads (BrdfData, w) pickles on stdin until its end, fits
each (`fit.fit_material`) and writes ("ok", MaterialFit) or ("error", message) pickles on
stdout.  Anything else the fit prints goes to stderr, so stdout carries only the pickles."""

from __future__ import annotations

import os
import pickle
import sys


def main() -> int:
    out = os.fdopen(os.dup(sys.stdout.fileno()), "wb")
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())
    inp = sys.stdin.buffer
    import scipy.optimize  # noqa: F401  (imported while the parent starts its own fit)

    from normbox_lab.analyze.fit import fit_material

    while True:
        try:
            data, w = pickle.load(inp)
        except EOFError:
            return 0
        try:
            reply: tuple[str, object] = ("ok", fit_material(data, w))
        except Exception as exc:  # noqa: BLE001 - the parent fits it again and raises it
            reply = ("error", f"{type(exc).__name__}: {exc}")
        pickle.dump(reply, out)
        out.flush()


if __name__ == "__main__":
    sys.exit(main())
