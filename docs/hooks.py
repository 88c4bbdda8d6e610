"""MkDocs hook: put the repository's own documents into the site under their repository paths.

The README is the home page and links to `notebooks/...` and `benchmarks/...` relative to the
repository root; giving each file its repository path as its site path keeps those links valid
in both places without a second copy of any text.
"""

from __future__ import annotations

import pathlib

from mkdocs.plugins import event_priority
from mkdocs.structure.files import File

SITE_PATHS = {"README.md": "index.md", "CHANGELOG.md": "changelog.md"}
"""Repository file -> its path in the site, where the two differ."""

GLOBS = ("README.md", "CHANGELOG.md", "notebooks/*.ipynb", "benchmarks/README.md",
         "benchmarks/*.py", "docs/assets/*.png")
"""Repository files that belong in the site (pages, or files that pages link to)."""


@event_priority(100)  # before mkdocs-jupyter's on_files, which claims the .ipynb files
def on_files(files, config):
    root = pathlib.Path(config.config_file_path).resolve().parent
    for pattern in GLOBS:
        for path in sorted(root.glob(pattern)):
            relative = path.relative_to(root).as_posix()
            if relative in SITE_PATHS:
                files.append(File.generated(config, SITE_PATHS[relative],
                                            abs_src_path=str(path)))
            else:
                # A plain File under the repository root, not a generated one: mkdocs-jupyter
                # wraps notebook files and finds their source through `src_dir`.
                files.append(File(relative, src_dir=str(root), dest_dir=config.site_dir,
                                  use_directory_urls=config.use_directory_urls))
    return files
