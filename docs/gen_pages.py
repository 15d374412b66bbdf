"""Pages made when the site is built (mkdocs-gen-files runs this): the reference pages from the code
(``torchtea.reference``) and the studies from ``experiments/`` (each folder's README and its other Markdown files,
so that their tables are the ones the studies' commands wrote)."""
from pathlib import Path

import mkdocs_gen_files

from torchtea.reference import PAGES, link_design_notes, sane_lists

ROOT = Path(__file__).resolve().parent.parent
EXPERIMENTS = ROOT / "experiments"

for path, page in PAGES.items():
    with mkdocs_gen_files.open(path, "w") as f:
        f.write(page())

index = (EXPERIMENTS / "README.md").read_text(encoding="utf-8")
folders = sorted(d for d in EXPERIMENTS.iterdir() if (d / "README.md").is_file())
index = index.replace("# Experiments", "# Studies", 1)
for d in folders:  # (the index's folders as links to their pages)
    index = index.replace(f"| `{d.name}/` |", f"| [{d.name}]({d.name}/index.md) |")


def studies_page(text: str, depth: int) -> str:
    """A study's Markdown as the site shows it: lists as Python-Markdown reads them, the design notes linked."""
    return link_design_notes(sane_lists(text), "../" * depth)


with mkdocs_gen_files.open("studies/index.md", "w") as f:
    f.write(studies_page(index, 1))
for d in folders:
    for md in sorted(d.glob("*.md")):
        if md.name == "LOG.md":  # (a folder's development log stays in the repository)
            continue
        name = "index.md" if md.name == "README.md" else md.name
        with mkdocs_gen_files.open(f"studies/{d.name}/{name}", "w") as f:
            f.write(studies_page(md.read_text(encoding="utf-8"), 2))


def loop_diagram() -> str:
    """The check's loop as an SVG drawn here (matplotlib), so that the home page shows it with no script loaded
    from elsewhere: the boxes, the diagnostics' decision, the arrows (from edge to edge of the boxes as drawn) and
    their labels."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.rcParams["svg.fonttype"] = "none"  # (text stays text: crisp at any size, found by the browser's search)
    boxes = {"R": (0.0, 1.0, "recording"), "F": (2.1, 1.0, "fit the model\nexact likelihood"),
             "D": (4.3, 1.0, "8 diagnostics:\nadequate?"), "S": (6.5, 1.0, "screen every\nmissing effect"),
             "A": (8.8, 1.0, "add the best,\nrefit, check again"), "T": (4.3, 0.0, "take away and swap\nwhile BIC falls"),
             "E": (6.7, 0.0, "model, ties,\nhow long to record"), "X": (9.0, 0.0, "export: Kalibr, VINS,\nORB-SLAM3, gtsam")}
    fig, ax = plt.subplots(figsize=(9.6, 2.6))
    ax.set_xlim(-0.7, 10.1)
    ax.set_ylim(-0.45, 1.85)
    ax.axis("off")
    drawn = {}
    for key, (x, y, text) in boxes.items():
        drawn[key] = ax.text(x, y, text, ha="center", va="center", fontsize=9, bbox={
            "boxstyle": "round,pad=0.4", "facecolor": "#fff3d6" if key == "D" else "#e8eef9", "edgecolor": "#4a5a78"})
    fig.canvas.draw()
    to_data = ax.transData.inverted()
    edge = {}  # each box's (left, right, bottom, top) in data units, as drawn
    for key, t in drawn.items():
        (x0, y0), (x1, y1) = to_data.transform(t.get_bbox_patch().get_window_extent().get_points())
        edge[key] = (x0, x1, y0, y1)
    style = {"arrowstyle": "-|>", "color": "#4a5a78", "shrinkA": 2, "shrinkB": 2}

    def arrow(start, end, rad=0.0):
        ax.annotate("", xy=end, xytext=start, arrowprops={**style, "connectionstyle": f"arc3,rad={rad}"})

    for a, b in (("R", "F"), ("F", "D"), ("D", "S"), ("S", "A"), ("T", "E"), ("E", "X")):
        y = boxes[a][1]
        arrow((edge[a][1], y), (edge[b][0], y))
    arrow((4.3, edge["D"][2]), (4.3, edge["T"][3]))
    arrow((boxes["A"][0], edge["A"][3]), (boxes["D"][0] + 0.3, edge["D"][3]), rad=0.25)
    ax.text((edge["D"][1] + edge["S"][0]) / 2, 1.1, "fails", ha="center", va="bottom", fontsize=8, color="#7a3d00")
    ax.text(4.4, (edge["D"][2] + edge["T"][3]) / 2, "adequate", ha="left", va="center", fontsize=8, color="#7a3d00")
    out = io.StringIO()
    fig.savefig(out, format="svg", bbox_inches="tight")
    plt.close(fig)
    return out.getvalue()


with mkdocs_gen_files.open("assets/loop.svg", "w") as f:
    f.write(loop_diagram())
