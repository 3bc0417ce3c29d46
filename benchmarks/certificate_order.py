"""How fast the certificate's box bound converges as boxes shrink, at the witness and on the
zeros of the recursion variables: second order at the witness, first order or slower on the
hyperplanes s_j = 0 of the levels whose small-exponent powers become variables of their own at
k < 0 (what makes r = 6 with k < 0 expensive).

For each row (r, k, gains): the witness state of the certificate's search (``certify`` with a
one-box cap: the seeded sample, climb and polish; deterministic), moved onto its face s_f = 1 by
the dilation. Boxes of half-width h in every face coordinate, centred on the witness (a local
maximum of R = dV1/dt / V1^alpha), and on the witness with one coordinate s_j set to 0 (the box
then contains the zero of s_j, where the powers of s_j with an exponent < 1 become variables of
their own: certificate.Ratio.boxes).

excess(h) = (the box's upper bound) - (the largest guaranteed lower bound of R at its centre, its
2^(r-1) corners and 4096 uniform points; tests/test_control_certificate.bound_excess): at least the
bound's over-estimate of max R on the box (the sampled maximum is below the true one, and the
corners hold the maximum of a function that is nearly linear on the box). order = log10(excess(h) / excess(h / 10)): 2 for the mean-value form's second order,
1 for first order. A box is discarded only when its excess is below the margin c, so an excess
slope of ~400 (r = 6, k = -0.002, on s_4 = 0) at c ~ 0.07 asks for widths ~2e-4 on every box of
the near-maximal set that contains the zero; at k = 0 the same boxes are second order.

    python -m benchmarks certificate_order [--rows 0,1,...]

Deterministic; one core, about 8 s of CPU.
"""

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from test_control_certificate import bound_excess, face_coordinates  # noqa: E402

from ftstab_mj.control import HongController, certify  # noqa: E402
from ftstab_mj.control.certificate import Ratio  # noqa: E402
from ftstab_mj.control.hong_terms import Terms  # noqa: E402

ROWS = [  # (r, k, gains, origin)
    (4, -0.05, (0.83467, 1.4216, 2.8157, 100.0), "designed"),
    (5, -0.01, (0.65, 1.2, 1.62, 12.63, 1000.0), "4 decades"),
    (6, 0.0, (0.62, 1.15, 1.54, 3.88, 39.13, 1e5), "k = 0, 6 decades"),
    (6, -0.002, (0.62, 1.15, 1.54, 3.88, 39.13, 1e5), "6 decades"),
]
WIDTHS = (1e-2, 1e-3, 1e-4, 1e-5, 1e-6)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", default=None, help="row numbers (0-based) to run, comma-separated")
    args = ap.parse_args(argv)
    rows = ROWS if args.rows is None else [ROWS[int(i)] for i in args.rows.split(",")]
    print("excess at h = " + ", ".join(f"{h:.0e}" for h in WIDTHS) + "; order = log10 of successive ratios")
    for r, k, gains, origin in rows:
        hong = HongController(r, k, gains)
        terms = Terms(r, k, gains)
        obj = Ratio(terms, "c")
        cert = certify(hong, max_boxes=1)
        f, x = face_coordinates(r, k, terms.s_of(np.array([cert.witness]))[0])
        print(f"r = {r}, k = {k}, gains {', '.join(f'{g:g}' for g in gains)} ({origin}): witness R = "
              f"{-cert.c_upper:.4g} on face s_{f + 1} = 1, s = ({', '.join(f'{v:.3g}' for v in np.insert(x, f, 1.0))})")
        centres = [("witness", x)]
        for j in range(r - 1):
            x0 = x.copy()
            x0[j] = 0.0
            centres.append((f"on s_{j + (j >= f) + 1} = 0", x0))
        for name, centre in centres:
            rng = np.random.default_rng(0)
            ex = [bound_excess(obj, f, centre, h, rng) for h in WIDTHS]
            order = [np.log10(a / b) if a > 0 and b > 0 else float("nan") for a, b in zip(ex, ex[1:])]
            print(f"  {name:>12}: excess " + "  ".join(f"{e:9.2e}" for e in ex)
                  + "   order " + " ".join(f"{o:5.2f}" for o in order))

if __name__ == "__main__":
    main()
