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
index = index.replace("# Experiments", "# Studies\n\nThe reproductions, studies and benchmarks of `experiments/`, each "
                      "folder's README as the folder has it (its command is named in it; run outputs stay out of git). "
                      "By folder: " + ", ".join(f"[{d.name}]({d.name}/index.md)" for d in folders) + ".", 1)


def studies_page(text: str, depth: int) -> str:
    """A study's Markdown as the site shows it: lists as Python-Markdown reads them, the design notes linked."""
    return link_design_notes(sane_lists(text), "../" * depth)


with mkdocs_gen_files.open("studies/index.md", "w") as f:
    f.write(studies_page(index, 1))
for d in folders:
    for md in sorted(d.glob("*.md")):
        name = "index.md" if md.name == "README.md" else md.name
        with mkdocs_gen_files.open(f"studies/{d.name}/{name}", "w") as f:
            f.write(studies_page(md.read_text(encoding="utf-8"), 2))
