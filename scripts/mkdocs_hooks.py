"""MkDocs hooks (mkdocs.yml ``hooks:``): the site serves the repository's own figures.

The benchmark's plots (``results/**/*.png``, written by ``tendon2r-benchmark``) and the arm's
picture (``results/default.png``, ``make view``) live outside ``docs/``; each is added to the
site as ``assets/<its repository path>``, without a copy in ``docs/``, so that a page can show
or link it and the strict build checks every such link.
"""

from __future__ import annotations

from pathlib import Path

from mkdocs.structure.files import File, Files

ROOT = Path(__file__).resolve().parent.parent
#: The repository folders whose PNGs the site serves, and the site folder they go under.
SERVED = ("results",)
ASSETS = "assets"


def on_files(files: Files, config) -> Files:
    for folder in SERVED:
        for path in sorted((ROOT / folder).rglob("*.png")):
            uri = f"{ASSETS}/{path.relative_to(ROOT).as_posix()}"
            if files.get_file_from_path(uri) is None:
                files.append(File.generated(config, uri, abs_src_path=str(path)))
    return files
