"""docs/python.md's snippets, run in order as one program in a scratch folder (matplotlib without a display)."""
import os
import re

import matplotlib

matplotlib.use("Agg")

SRC = os.environ.get("KELVIN_SOURCE_DIR", os.path.join(os.path.dirname(__file__), "..", ".."))


def test_the_snippets_of_docs_python_md_run(tmp_path, monkeypatch):
    with open(os.path.join(SRC, "docs", "python.md"), encoding="utf-8") as f:
        blocks = re.findall(r"```python\n(.*?)```", f.read(), re.S)
    assert len(blocks) >= 8
    monkeypatch.chdir(tmp_path)
    namespace = {"__name__": "docs_python"}
    for i, code in enumerate(blocks):
        exec(compile(code, f"docs/python.md, snippet {i + 1}", "exec"), namespace)
    for name in ("cornell.exr", "cornell-preview.png", "depth-sweep.png", "study.png", "vorticity.png"):
        assert (tmp_path / name).stat().st_size > 0, name
