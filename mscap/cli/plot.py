"""``mscap plot results.h5 -o fig.png``: the best optimised layout per k of a multi-start
results file, the chosen k highlighted, and the best metric against k (paper Fig. 10)."""

from __future__ import annotations

__all__ = ["add_parser", "run"]


def add_parser(sub) -> None:
    p = sub.add_parser("plot", help="plot the best layout per k of a multi-start results file (HDF5)",
                       description="Draw a grid of the best optimised layout per k (sheet outline, plates "
                                   "coloured, the metric in the title: the read-back bound in mm for a scene "
                                   "designed for read-back (⊕ the map's noise with distance = readback), else the "
                                   "min pairwise L1 distance of the poses' "
                                   "capacitance vectors in pF), the chosen k framed, and a panel of the best "
                                   "metric against "
                                   "k with the plateau tolerance band of the chosen k (paper Fig. 10). "
                                   "The selection is recomputed from the stored runs (see docs/hdf5.md).")
    p.add_argument("results", help="results file (.h5)")
    p.add_argument("-o", "--output", metavar="FIGURE.png", required=True,
                   help="figure file: .png (also a name without a suffix), .pdf, .svg, ...")
    p.add_argument("--dpi", type=int, default=120, help="resolution (dots per inch)")
    p.set_defaults(run=run)


def run(args) -> int:
    from pathlib import Path

    from mscap.errors import MscapError
    from mscap.outputs import output_directory, replace_file
    from mscap.viz.layouts import figure_format, plot_results

    try:
        fmt = figure_format(args.output)
    except ValueError as exc:
        raise MscapError(f"plot -o {exc}") from None
    # Written beside its name and renamed over it: a link there is replaced, never followed
    # (the figure went to the link's target), and a failed plot leaves no partial file.
    output_directory(Path(args.output).parent, "plot -o")
    drawn = []
    replace_file(args.output, lambda path: drawn.extend(plot_results(args.results, path, dpi=args.dpi, fmt=fmt)))
    items = drawn
    chosen = next((p.k for p in items if p.chosen), None)
    print(f"wrote {args.output}: {len(items)} k value(s)"
          + (f", chosen k = {chosen}" if chosen is not None else ", no k chosen"))
    return 0
