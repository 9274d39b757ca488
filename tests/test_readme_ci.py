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


def test_packaging_metadata():
    """[all] is what a user needs (no test tools); tests install [all,dev]; typed; SPDX license."""
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        import tomli as tomllib
    meta = tomllib.loads((ROOT / "pyproject.toml").read_text())
    project, extras = meta["project"], meta["project"]["optional-dependencies"]
    user = " ".join(extras["all"])
    for tool in ("pytest", "hypothesis", "dev"):
        assert tool not in user, f"[all] pulls in {tool}"
    assert {d.split(">")[0].split("=")[0] for d in extras["dev"]} >= {"pytest", "hypothesis", "pytest-timeout"}
    for name in ("fmu", "cad", "cell", "cosim"):
        assert name in user
    assert "'.[all,dev]'" in _block("test-command") and "'.[all]'" in _block("main-command")
    assert project["license"] == "MIT" and not any(c.startswith("License ::") for c in project["classifiers"])
    assert any(r.startswith("setuptools>=7") and int(r.split(">=")[1].split(".")[0]) >= 77
               for r in meta["build-system"]["requires"])  # SPDX expressions need setuptools >= 77
    assert "py.typed" in meta["tool"]["setuptools"]["package-data"]["mtcomp"]
    assert (ROOT / "core" / "py.typed").exists()


def test_readme_python_example_runs(monkeypatch):
    """The README's API example runs as printed (it once used an undefined `q_programmed`), from
    the checkout's root where its relative paths point."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    m = re.search(r"```python\n(.*?)```", text, re.S)
    assert m, "README.md has no python example"
    monkeypatch.chdir(ROOT)
    exec(compile(m.group(1), "README.md", "exec"), {})


def test_library_never_switches_the_matplotlib_backend():
    """Issue 19: ten library plot functions called matplotlib.use("Agg") and drew through pyplot,
    which switched a notebook's backend.  Plots are matplotlib.figure.Figure objects now; the
    runtime checks are in test_demo, test_diagnose_real and test_fmu_cosim, and this guard keeps
    every module of the package free of backend switching and pyplot state."""
    offenders = []
    for folder in ("core", "fmu", "cad_plugin"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
                code = line.split("#", 1)[0]
                if re.search(r"matplotlib\.use\(|import matplotlib\.pyplot|from matplotlib import pyplot|plt\.(figure|subplots)\(",
                             code):
                    offenders.append(f"{path.relative_to(ROOT)}:{n}: {line.strip()}")
    assert not offenders, "\n".join(offenders)
