"""The tuning grids' part of the study's results page (``eval.objectnav.study_report``): Success
against the goal threshold on the tuning episodes per tuned row, as a table and as a figure
with the transferred thresholds marked, and the rows whose best threshold sits on an edge of
their extended grid."""
from __future__ import annotations

from pathlib import Path


def transfer_pairs(manifest: dict) -> list[tuple[str, str]]:
    """[row, its condition's own tuned row] for every row that takes another row's threshold
    and has a tuned row with the same overrides (neither of them a row the study leaves out)."""
    rows = manifest["rows"]
    out = []
    for name, e in rows.items():
        if e.get("threshold_from") and e.get("status") != "left_out":
            own = next((n for n, o in rows.items() if not o.get("threshold_from") and o["overrides"] == e["overrides"]
                        and o.get("status") != "left_out"), None)
            if own is not None:
                out.append((name, own))
    return out


def transferred_thresholds(manifest: dict) -> dict[str, list[tuple[float, str]]]:
    """{tuned row: [(threshold, the row it comes from)]} for each other condition's tuned threshold
    a row of the same condition is evaluated at (``transfer_pairs``), once the source has tuned."""
    rows, out = manifest["rows"], {}
    for at, own in transfer_pairs(manifest):
        source = rows[at]["threshold_from"]
        t = rows.get(source, {}).get("threshold")
        if t is not None and (t, source) not in out.get(own, []):
            out.setdefault(own, []).append((t, source))
    return out


def tuned_grids(manifest: dict) -> dict[str, tuple[dict, list[dict]]]:
    """{row: (its tune entry, its grid at the chosen min_area, by threshold)} for every row that
    tuned its own threshold, in study order."""
    out = {}
    for name, e in manifest["rows"].items():
        t = e.get("tune")
        if t and not e.get("threshold_from") and t.get("grid"):
            grid = sorted((r for r in t["grid"] if t.get("min_area") is None or r.get("min_area") == t["min_area"]),
                          key=lambda r: r["threshold"])
            out[name] = (t, grid)
    return out


def grids_markdown(manifest: dict) -> str:
    """Per tuned row: Success (SEM) at each threshold tried, the chosen one in bold; "" when no
    row has tuned yet."""
    grids = tuned_grids(manifest)
    if not grids:
        return ""
    tune = manifest["tune"]
    transferred = transferred_thresholds(manifest)
    lines = [f"| Row | Success (SEM) on {tune['split']} {tune['episodes']} at each goal threshold tried | Chosen | "
             "Also evaluated at |", "|---|---|---|---|"]
    for name, (t, grid) in grids.items():
        cells = []
        for r in grid:
            cell = f"{r['threshold']:g}: {r['success']:.3f} ({r['success_sem']:.3f})"
            cells.append(f"**{cell}**" if r["threshold"] == t["threshold"] else cell)
        also = ", ".join(f"{x:g} ({src})" for x, src in transferred.get(name, [])) or "-"
        lines.append(f"| {name} | {', '.join(cells)} | {t['threshold']:g} | {also} |")
    return "\n".join(lines)


def plot_curves(manifest: dict, path: Path) -> Path | None:
    """Success vs goal threshold on the tuning episodes, one line per tuned row (+-1 SEM), the
    chosen point circled, and a dotted line (a cross where it is on the grid) at each other
    condition's threshold the row's condition is evaluated at (``transfer_pairs``); None when no
    row has tuned yet."""
    tuned = tuned_grids(manifest)
    if not tuned:
        return None
    from calnav.eval.objectnav.report import _plt

    plt = _plt()
    transferred = transferred_thresholds(manifest)
    groups = sorted({n.rsplit("/", 1)[0] for n in tuned})
    fig, axes = plt.subplots(1, len(groups), figsize=(4.2 * len(groups), 3.4), squeeze=False, sharey=True)
    for ax, group in zip(axes[0], groups):
        for n, (t, grid) in tuned.items():   # the chosen min_area's curve
            if n.rsplit("/", 1)[0] != group:
                continue
            line = ax.errorbar([r["threshold"] for r in grid], [r["success"] for r in grid],
                               yerr=[r["success_sem"] for r in grid], marker=".", capsize=3, label=n.rsplit("/", 1)[1])
            best = next(r for r in grid if r["threshold"] == t["threshold"])
            ax.plot([best["threshold"]], [best["success"]], "o", mfc="none", ms=10, color=line[0].get_color())
            for x, _ in transferred.get(n, []):   # another condition's threshold this row's condition is evaluated at
                ax.axvline(x, ls=":", lw=1, color=line[0].get_color())
                ax.plot([r["threshold"] for r in grid if r["threshold"] == x],
                        [r["success"] for r in grid if r["threshold"] == x], "x", ms=8, color=line[0].get_color())
        ax.set_title(group, fontsize=9)
        ax.set_xlabel("goal threshold")
        ax.legend(fontsize=7)
    axes[0][0].set_ylabel(f"Success on {manifest['tune']['split']} {manifest['tune']['episodes']} (+-1 SEM)")
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)
    return path


def edge_rows(manifest: dict) -> list[tuple[str, float]]:
    """(row, tuned threshold) of the rows whose best threshold still sits on an edge of their
    grid after its extensions, beating its neighbour (``eval.objectnav.tune.edge_extension``):
    their optimum may lie beyond the grid."""
    from calnav.eval.objectnav.tune import edge_extension, grid_scores

    metric = manifest["tune"].get("metric", "success")
    return [(n, e["threshold"]) for n, e in manifest["rows"].items()
            if e.get("tune") and not e.get("threshold_from") and e["tune"].get("grid")
            and edge_extension(grid_scores(e["tune"]["grid"], metric)) is not None]
