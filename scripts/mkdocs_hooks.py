"""MkDocs hooks: serve benchmarks/results/*.md as results/*.md in the site.

The measured figures live beside the benchmarks that write them (benchmarks/results/), and the
user pages link there with repository-relative paths (../benchmarks/results/X.md), which work
on GitHub. The site only sees docs/, so these hooks add the results pages to it and rewrite
the links both ways; the Markdown files stay the single source.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from mkdocs.structure.files import File, Files

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"


def on_files(files: Files, config: Any) -> Files:
    for path in sorted(RESULTS.glob("*.md")):
        files.append(File.generated(config, f"results/{path.name}", abs_src_path=str(path)))
    return files


def on_page_markdown(markdown: str, page: Any, config: Any, files: Files) -> str:
    if page.file.src_uri.startswith("results/"):
        # benchmarks/results/X.md links to ../../docs/Y.md; in the site results/ sits in docs/.
        return re.sub(r"\]\(\.\./\.\./docs/", "](../", markdown)
    return re.sub(r"\]\(\.\./benchmarks/results/", "](results/", markdown)
