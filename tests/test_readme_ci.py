"""The README's test command is what CI runs, and the documented files exist."""
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _block(name):
    text = (ROOT / "README.md").read_text()
    m = re.search(rf"<!-- {name} -->\s*```\s*\n(.*?)\n```\s*\n<!-- /{name} -->", text, re.S)
    assert m, f"README.md has no {name} block"
    return m.group(1).strip()


def test_ci_runs_the_readme_test_command():
    """The command .ci/run extracts from README.md (with its own sed line) is the README's block."""
    import subprocess
    ci = (ROOT / ".ci" / "run").read_text()
    extract = next(line for line in ci.splitlines() if line.startswith("cmd=$("))[len("cmd=$("):-1]
    got = subprocess.run(["bash", "-c", extract], cwd=ROOT, capture_output=True, text=True, check=True).stdout
    assert got.strip() == _block("test-command")
    assert "pytest" in got and "pip install" in got


def test_main_command_uses_shipped_files():
    cmd = _block("main-command")
    for token in cmd.split():
        if token.startswith(("examples/", "docs/")):
            assert (ROOT / token).exists(), token


def test_documented_docs_exist():
    text = (ROOT / "README.md").read_text()
    for link in re.findall(r"\]\((docs/[^)]+)\)", text):
        assert (ROOT / link).exists(), link
