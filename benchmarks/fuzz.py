"""Fuzz campaign over every input surface of the `mtcomp` command line (issue 15).

For each surface a valid seed file is made with mtcomp itself, then mutated (bytes, numbers
replaced by hostile values, lines deleted, duplicated, swapped or cut) and fed to the command
that reads it.  Each input runs in a forked child of this process (mtcomp imported once, so an
input costs milliseconds, not an interpreter start) with a wall-time bound and a memory limit,
and is classified:

* refused: exit status 2 with one error line (what bad input must give);
* traceback: a Python traceback, an "internal error" (status 3), any other status or a signal;
* hang: still running at the time bound (the child's process group is killed);
* half-written: a temporary file left next to an output, or an output written by a failed run;
* silent-wrong (NC programs only): with zero errors, `compensate` must reproduce the program
  byte for byte; an accepted program that comes out different changed geometry silently.

Counts per surface go to docs/benchmarks.md (section "fuzz"); the first input of every distinct
failure is kept in --repro-dir with the command line that fails on it.

    python benchmarks/fuzz.py --per-surface 40               # short campaign (about 2 min CPU)
    python benchmarks/fuzz.py --per-surface 10000 --timeout 30 --jobs 2   # the acceptance run
"""
from __future__ import annotations

import argparse
import json
import os
import random
import re
import resource
import shutil
import signal
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # forked children must not share a BLAS pool
os.environ.setdefault("OMP_NUM_THREADS", "1")
ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))

from mtcomp.gcode.provenance import strip_header  # noqa: E402

SMALL5 = ("O0001 (fuzz seed)\nG21 G90 G17\nN10 G0 X0 Y0 Z5. B0 C0\nN20 G1 Z0 F200\n"
          "N30 X5.0 Y2 C30.5 ; cut\nN40 G2 X7. Y2. I1. J-2.\nN50 G1 Y-3.25 B20\nN60 G0 Z5.\nM30\n")
# arcs the issue found read wrongly: a full circle, a 3-decimal arc, small G91 increments
ARCS = ("O0002 (fuzz seed: arcs)\nG21 G90 G17\nG0 X0 Y0 Z1. B0 C0\nG1 X1. Y0 F100\nG2 X1. Y0 I-1. J0\n"
        "G1 X10. Y0\nG3 X5.403 Y8.415 I-10. J0\nG2 X6.5 Y8. R1.5\nG91 G1 X0.001 Y-0.002\nG90 G0 Z5.\nM30\n")
POSE = "0.05,-0.03,0.02,0.1,-0.2,0.3"
# tool lengths (G43 H, a tool change) and work offsets (G54/G55): the programs the tool table and
# the offsets file are read for
G43 = ("O0003 (fuzz seed: tool lengths)\nG21 G90 G17\nT1 M6\nG54 G0 X0 Y0 B0 C0\nG43 H1 Z5.\nG1 Z0 F200\n"
       "X5. Y2.\nG0 Z5.\nT2 M6\nG0 X1. Y1.\nG43 H2 Z5.\nG1 Z-0.5 F100\nG2 X3. Y1. I1. J0\nG0 Z5.\nG49\nM30\n")
G43W = G43.replace("T2 M6\nG0 X1.", "T2 M6\nG55 G0 X1.")
TOOL_TABLE = "T1 P1 Z+5.0 D6.0 ;end mill\nT2 P2 Z+7.5 D3.0\nT3 P3 Z+2.25\n"
OFFSETS = "[H]\n1 = 5.0\n2 = 7.5\n[D]\n1 = 3.0\n[G54]\nX = 0.0\nY = 0.0\n[G55]\nX = 1.0\nY = -2.0\n"
HOSTILE = ["nan", "inf", "-inf", "1e308", "1e400", "-0", "0", "-1", "", "true", '"x"', "[]", "{}",
           "99999999999999999999", "1e-320", "5e-6", "0.0000004", "1" * 320, "abc", "1,5", "\u0661",
           "9.3e12", "-1e12", "2147483648", "1e-9", "-0.0000004", "0.000001", "10.000001"]
NUM_RE = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")


# ---------------------------------------------------------------------------------------------
# mutations

def mutate(text: str, rng: random.Random, pool: list[str]) -> str:
    """One to three random edits of `text`; pool: lines of other seeds to splice in."""
    for _ in range(rng.randint(1, 3)):
        lines = text.split("\n")
        op = rng.randrange(9)
        if op <= 2:  # replace a number by a hostile value (the most productive edit)
            nums = list(NUM_RE.finditer(text))
            if nums:
                m = rng.choice(nums)
                text = text[:m.start()] + rng.choice(HOSTILE) + text[m.end():]
                continue
        if op == 3 and lines:
            del lines[rng.randrange(len(lines))]
        elif op == 4 and lines:
            i = rng.randrange(len(lines))
            lines.insert(i, lines[i])
        elif op == 5 and len(lines) > 1:
            i, j = rng.randrange(len(lines)), rng.randrange(len(lines))
            lines[i], lines[j] = lines[j], lines[i]
        elif op == 6 and text:
            text = text[:rng.randrange(len(text))]
            continue
        elif op == 7 and text:  # one character replaced, inserted or deleted
            i = rng.randrange(len(text))
            c = rng.choice([",", "\n", "#", "=", "[", "]", '"', " ", "\x00", "\r", "\ufeff", "-", ".", "e", "G", "X"])
            k = rng.randrange(3)
            text = text[:i] + (c if k < 2 else "") + text[i + (k != 1):]
            continue
        elif pool:
            lines.insert(rng.randrange(len(lines) + 1), rng.choice(pool))
        text = "\n".join(lines)
    if rng.random() < 0.05 and not text.startswith("\ufeff"):
        text = "\ufeff" + text      # a byte-order mark in front, as some editors save programs
    return text


# ---------------------------------------------------------------------------------------------
# surfaces: seed file + command line ({f}: the mutated file, {o}: the output folder, {s}: seeds)

def make_seeds(s: Path) -> dict:
    """Write a valid input of every surface into folder s (with mtcomp itself)."""
    from mtcomp.cli import main
    from mtcomp.errors import AxisErrorTable, ErrorSet, GeometricErrors, save_errors

    def run(*argv):
        with open(os.devnull, "w") as null:
            old = sys.stdout
            sys.stdout = null
            try:
                rc = main([str(a) for a in argv])
            finally:
                sys.stdout = old
        assert rc == 0, argv
    shutil.copy(ROOT / "examples/programs/groove5x.nc", s / "groove5x.nc")
    shutil.copy(ROOT / "examples/errors/setting-example.toml", s / "setting.toml")
    (s / "small5.nc").write_text(SMALL5)
    # dialect features: G16 polar words, cycle repeat counts (Fanuc K, LinuxCNC L), G43.1
    for name in ("fanuc_polar.nc", "fanuc_repeat.nc", "linuxcnc_repeat.ngc", "linuxcnc_g43_1.ngc"):
        shutil.copy(ROOT / "tests/data/nc" / name, s / name)
    (s / "arcs.nc").write_text(ARCS)
    (s / "zero.toml").write_text("# no errors\n")
    (s / "g43.nc").write_text(G43)
    (s / "g43w.nc").write_text(G43W)
    (s / "tool.tbl").write_text(TOOL_TABLE)
    (s / "toolh.tbl").write_text("T12 P1 H1 Z+5.0\nT7 P2 H2 Z+7.5 D3.\n")
    (s / "offsets.toml").write_text(OFFSETS)
    tab = AxisErrorTable("X", [-150.0, 0.0, 150.0], {"EXX": [0.001, 0.0, -0.002], "EBX": [2e-6, 0.0, 1e-6]})
    save_errors(ErrorSet(geometric=GeometricErrors({"X": tab}, {"EC0Y": 1e-5, "EB0Z": -8e-6})), s / "geo.toml")
    shutil.copy(ROOT / "core/presets/robonano-a0ib.toml", s / "machine.toml")
    (s / "ts").mkdir()
    run("tool-setting", "plan", "-o", s / "ts")
    run("tool-setting", "simulate", "--plan", s / "ts/plan.toml", "--offset", "0.34", "0.245", "0.2", "--seed", "3",
        "-o", s / "ts/measured.csv")
    (s / "wp").mkdir()
    run("workpiece-setting", "plan", "-o", s / "wp/plan.toml")
    run("workpiece-setting", "probe", s / "wp/plan.toml", "--pose", POSE, "--noise", "0.0003", "--seed", "2",
        "-o", s / "wp/touches.csv")
    (s / "geo").mkdir()
    run("geometric", "simulate", "-o", s / "geo/set.toml", "--seed", "1")
    from mtcomp.diagnose import synth
    case = synth.make_case(["squareness"], seed=4, duration=6.0, sim_rate=100.0, rec_rate=50.0)
    (s / "diag").mkdir()
    synth.write_csv(s / "diag/sim.csv", case.sim)
    synth.write_csv(s / "diag/rec.csv", case.rec)
    job = {"job_no": 1, "program": 1, "blank": 7}
    recs = [{"ev": "boot", "state": "idle"}, {"ev": "start", "cmd_seq": 1, "status": 0, "job": job},
            {"ev": "result", "result_seq": 1, "job": job, "pose": [0.01, -0.02, 0.0, 0.0, 0.0, 0.1]},
            {"ev": "ack", "cmd_seq": 2, "status": 0, "result_seq": 1},
            {"ev": "fault", "code": 3, "name": "PROBE_TIMEOUT", "why": "no touches", "job": job},
            {"ev": "reset", "cmd_seq": 3, "status": 0}]
    (s / "journal.jsonl").write_text("".join(json.dumps({"n": i + 1, "t": 1.0 + i, **r}) + "\n"
                                             for i, r in enumerate(recs)))
    return {
        # name: (seed file or files, file name in the input folder, command line, extra files to place beside)
        "nc-program": ([s / "small5.nc", s / "arcs.nc", s / "groove5x.nc", s / "fanuc_polar.nc",
                        s / "fanuc_repeat.nc", s / "linuxcnc_repeat.ngc", s / "linuxcnc_g43_1.ngc"], "p.nc",
                       ["compensate", "{f}", "-m", "robonano-a0ib", "-e", "{s}/zero.toml", "-o", "{o}/out.nc"], []),
        "errors-toml": (s / "setting.toml", "e.toml",
                        ["compensate", "{s}/small5.nc", "-m", "robonano-a0ib", "-e", "{f}", "-o", "{o}/out.nc"],
                        [s / "geo_X.csv"]),
        "errors-csv": (s / "geo_X.csv", "geo_X.csv",
                       ["compensate", "{s}/small5.nc", "-m", "robonano-a0ib", "-e", "{d}/geo.toml", "-o",
                        "{o}/out.nc"], [s / "geo.toml"]),
        "machine-toml": (s / "machine.toml", "m.toml",
                         ["compensate", "{s}/small5.nc", "-m", "{f}", "-e", "{s}/setting.toml", "-o", "{o}/out.nc"], []),
        "tool-setting-plan": (s / "ts/plan.toml", "plan.toml",
                              ["tool-setting", "simulate", "--plan", "{f}", "--offset", "0.3", "0.2", "0.1",
                               "--seed", "1", "-o", "{o}/m.csv"], []),
        "tool-setting-sheet": (s / "ts/measured.csv", "measured.csv",
                               ["tool-setting", "estimate", "{f}", "--plan", "{s}/ts/plan.toml", "-o", "{o}/e.toml"], []),
        "workpiece-plan": (s / "wp/plan.toml", "plan.toml",
                           ["workpiece-setting", "probe", "{f}", "--pose", POSE, "-o", "{o}/t.csv"], []),
        "workpiece-touches": (s / "wp/touches.csv", "touches.csv",
                              ["workpiece-setting", "fit", "{s}/wp/plan.toml", "{f}", "-o", "{o}/e.toml"], []),
        "geometric-set": (s / "geo/set.toml", "set.toml", ["geometric", "build", "{f}", "-o", "{o}/e.toml"],
                          sorted((s / "geo").glob("set_E*.csv"))),
        "iso230-2-run": (s / "geo/set_EXX.csv", "run.csv", ["geometric", "iso230-2", "{f}", "-o", "{o}/r"], []),
        "diagnose-csv": (s / "diag/rec.csv", "rec.csv",
                         ["diagnose", "--sim", "{s}/diag/sim.csv", "--rec", "{f}", "--json", "{o}/d.json"], []),
        "tool-table": ([s / "tool.tbl", s / "toolh.tbl"], "tool.tbl",
                       ["compensate", "{s}/g43.nc", "-m", "robonano-a0ib", "-e", "{s}/setting.toml",
                        "--tool-table", "{f}", "-o", "{o}/out.nc"], []),
        "offsets-toml": (s / "offsets.toml", "offsets.toml",
                         ["compensate", "{s}/g43w.nc", "-m", "robonano-a0ib", "-e", "{s}/setting.toml",
                          "--offsets", "{f}", "-o", "{o}/out.nc"], []),
        "cell-journal": (s / "journal.jsonl", "journal.jsonl", ["<journal>", "{f}"], []),
        "cli-options": (None, None, None, []),
    }


OPTION_TOKENS = ["-o", "--out", "--output", "-m", "--machine", "-e", "--errors", "--plan", "--seed", "--pose",
                 "--offset", "--chordal-tol", "--noise", "--step", "--png", "--report", "--json", "--debug",
                 "--help", "--where", "--exclude-rows", "--same-clock", "x!=50", "t >= 1", "name==Prep", "x=", "--tool-table", "--offsets", "--tool-lengths", "1=5,2=7.5", "--start", "X=1,Y=2", "--unknown", "defer", "refuse", "--cutter-radius", "{s}/g43.nc", "{s}/tool.tbl", "{s}/offsets.toml", "--", "-", "0", "-1", "nan", "inf", "1e400", "abc", "1,2,3", "0,0,0,0,0,0",
                 "robonano-a0ib", "no-such", "", "/dev/null", "/dev/zero", "{o}", "{o}/x", "{o}/none/x",
                 "{s}/small5.nc", "{s}/setting.toml", "{s}/wp/plan.toml", "{s}/ts/plan.toml", "{s}/geo/set.toml"]
COMMANDS = [["compensate"], ["machines"], ["tool-setting", "plan"], ["tool-setting", "simulate"],
            ["tool-setting", "estimate"], ["workpiece-setting", "plan"], ["workpiece-setting", "probe"],
            ["workpiece-setting", "fit"], ["geometric", "iso230-2"], ["geometric", "build"],
            ["geometric", "simulate"], ["diagnose"], ["model", "export"]]


# ---------------------------------------------------------------------------------------------
# running one input in a forked child

def run_child(argv: list[str], out_dir: Path, timeout: float, mem_bytes: int) -> tuple[str, int, str, float]:
    """Run `mtcomp argv` (or the journal reader) in a forked child. Returns (status, rc, stderr,
    cpu seconds) with status in ok | hang | signal."""
    err_path = out_dir.parent / "stderr.txt"
    t0 = os.times()
    pid = os.fork()
    if pid == 0:  # child
        rc = 99
        try:
            os.setpgid(0, 0)
            resource.setrlimit(resource.RLIMIT_AS, (mem_bytes, mem_bytes))
            fd_out = os.open(os.devnull, os.O_WRONLY)
            fd_err = os.open(err_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
            os.dup2(fd_out, 1)
            os.dup2(fd_err, 2)
            fd_in = os.open(os.devnull, os.O_RDONLY)
            os.dup2(fd_in, 0)
            sys.stdout = open(1, "w", closefd=False)
            sys.stderr = open(2, "w", closefd=False)
            os.chdir(out_dir)
            if argv[0] == "<journal>":
                rc = journal_main(argv[1])
            else:
                from mtcomp.cli import main
                try:
                    rc = main(argv)
                except SystemExit as exc:
                    rc = exc.code if isinstance(exc.code, int) else 2
            sys.stdout.flush()
            sys.stderr.flush()
        except BaseException:  # noqa: BLE001 - a traceback escaping main is what we count
            import traceback
            traceback.print_exc()
            sys.stderr.flush()
            rc = 98
        os._exit(rc if isinstance(rc, int) else 97)
    deadline = time.monotonic() + timeout
    status, code = "ok", 0
    while True:
        done, st = os.waitpid(pid, os.WNOHANG)
        if done:
            if os.WIFSIGNALED(st):
                status, code = "signal", os.WTERMSIG(st)
            else:
                code = os.WEXITSTATUS(st)
            break
        if time.monotonic() > deadline:
            try:
                os.killpg(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            os.waitpid(pid, 0)
            status, code = "hang", -1
            break
        time.sleep(0.002)
    t1 = os.times()
    cpu = (t1.children_user - t0.children_user) + (t1.children_system - t0.children_system)
    try:
        err = err_path.read_text(errors="replace")
    except OSError:
        err = ""
    return status, code, err, cpu


def journal_main(path: str) -> int:
    """What `mtcomp cell serve --journal` does with the journal before serving: open (repair a
    torn tail) and replay it.  Exit status like the CLI's."""
    from mtcomp._io import MtcompError
    from mtcomp.cell.journal import Journal, replay
    try:
        j = Journal.open(path)
        try:
            replay(j.records)
        finally:
            j.close()
    except MtcompError as exc:
        print(f"mtcomp cell: error: {exc}", file=sys.stderr)
        return 2
    except Exception as exc:  # noqa: BLE001
        print(f"mtcomp cell: internal error: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 3
    return 0


def changed_block(src: Path, out: Path) -> str:
    """The shape of the first input block the identity rewrite changed, e.g. 'G3 X Y I J'."""
    a = src.read_text(errors="replace").split("\n")
    b = out.read_text(errors="replace").split("\n") if out.exists() else []
    for i, line in enumerate(a):
        if i >= len(b) or b[i] != line:
            words = re.findall(r"([A-Z])([-+.\d]+)", line.upper())
            shape = " ".join(a + (v if a == "G" else "") for a, v in words) or line[:30]
            return f"'{shape}' blocks"
    return "(lines added)"


def signature(err: str, status: str, code: int) -> str:
    """A short key that groups failures of one cause."""
    if status == "hang":
        return "hang"
    if status == "signal":
        return f"signal {code}"
    m = re.search(r"internal error: (\w+)(?: at ([\w.]+:\d+))?", err)
    if m:
        return f"{m.group(1)} at {m.group(2) or '?'}"
    frames = re.findall(r'File "([^"]+)", line (\d+)', err)
    last = re.findall(r"^(\w+(?:Error|Exception|Exit)?):", err, re.M)
    if frames:
        return f"{last[-1] if last else 'Traceback'} at {Path(frames[-1][0]).name}:{frames[-1][1]}"
    return f"exit {code}"


# ---------------------------------------------------------------------------------------------

def campaign(per_surface: int, seed: int, timeout: float, surfaces: list[str] | None, repro_dir: Path | None,
             mem_mb: int, show: bool = False) -> dict:
    import mtcomp.cli  # noqa: F401 - imported once, before forking
    for mod in ("mtcomp.commands", "mtcomp.gcode", "mtcomp.kinematics", "mtcomp.setting.tool_cli",
                "mtcomp.setting.workpiece_cli", "mtcomp.geometric.cli", "mtcomp.diagnose.cli",
                "mtcomp.cell.journal", "matplotlib.figure", "scipy.optimize", "scipy.linalg"):
        try:
            __import__(mod)
        except ImportError:
            pass
    work = Path(tempfile.mkdtemp(prefix="mtcomp-fuzz-"))
    try:
        s = work / "seeds"
        s.mkdir()
        table = make_seeds(s)
        pool = []
        for name, (f, *_rest) in table.items():
            for x in (f if isinstance(f, list) else [f] if f is not None else []):
                pool += [ln for ln in x.read_text(errors="replace").split("\n") if ln.strip()][:40]
        results = {}
        for name, (seed_file, fname, argv_t, extras) in table.items():
            if surfaces and name not in surfaces:
                continue
            rng = random.Random(f"{seed}:{name}")
            seeds = seed_file if isinstance(seed_file, list) else [seed_file] if seed_file is not None else []
            bases = [x.read_text() for x in seeds]
            counts = dict(tried=0, accepted=0, refused=0, tracebacks=0, hangs=0, half_written=0,
                          silent_wrong=0, cpu=0.0)
            kinds: dict[str, dict] = {}
            for i in range(per_surface):
                d = work / "in" / f"{name}-{i}"
                o = d / "out"
                o.mkdir(parents=True)
                for x in extras:
                    shutil.copy(x, d / x.name)
                if seed_file is None:  # CLI options: random command lines
                    argv = list(rng.choice(COMMANDS)) + [rng.choice(OPTION_TOKENS) for _ in range(rng.randint(0, 8))]
                    text = None
                else:
                    text = mutate(rng.choice(bases), rng, pool)
                    (d / fname).write_bytes(text.encode("utf-8", "surrogatepass"))
                    argv = list(argv_t)
                argv = [a.replace("{f}", str(d / (fname or ""))).replace("{o}", str(o)).replace("{s}", str(s))
                        .replace("{d}", str(d)) for a in argv]
                status, code, err, cpu = run_child(argv, o, timeout, mem_mb << 20)
                if show:
                    print(f"  [{name} {i}] {status} {code}: {(err.strip().splitlines() or [''])[-1][:160]}")
                counts["tried"] += 1
                counts["cpu"] += cpu
                bad = None
                if status == "hang":
                    counts["hangs"] += 1
                    bad = "hang"
                elif (status == "signal" or code not in (0, 2) or "internal error" in err
                      # --debug asks for the traceback of a refusal too: status 2 with --debug is a refusal
                      or ("Traceback" in err and not (code == 2 and "--debug" in argv))):
                    counts["tracebacks"] += 1
                    bad = signature(err, status, code)
                elif code == 2:
                    counts["refused"] += 1
                else:
                    counts["accepted"] += 1
                left = [p for p in o.rglob("*") if p.name.endswith(".tmp")]
                if left or (code != 0 and status == "ok" and any(p.is_file() for p in o.rglob("*"))):
                    counts["half_written"] += 1
                    bad = bad or "half-written"
                if name == "nc-program" and code == 0 and status == "ok":
                    outp = o / "out.nc"
                    # the compensated program carries mtcomp's provenance header: the rest must
                    # be the input byte for byte (zero errors)
                    # (and a byte-order mark stays the first bytes: the rest is then the input
                    # even with the header in front of the mark, a stray character to a control)
                    src = (d / fname).read_bytes()
                    out = outp.read_bytes() if outp.exists() else None
                    if out is None or (strip_header(out.decode("utf-8")).encode("utf-8") != src) or \
                            (src.startswith(b"\xef\xbb\xbf") and not out.startswith(b"\xef\xbb\xbf")):
                        counts["silent_wrong"] += 1
                        bad = bad or f"identity changed {changed_block(d / fname, outp)}"
                if bad:
                    k = kinds.setdefault(bad, {"count": 0, "example": None})
                    k["count"] += 1
                    if k["example"] is None:
                        k["example"] = {"argv": argv, "stderr": err.strip().splitlines()[-1:] if err.strip() else [],
                                        "input": text}
                        if repro_dir is not None and text is not None:
                            rd = repro_dir / name
                            rd.mkdir(parents=True, exist_ok=True)
                            slug = re.sub(r"[^\w.-]+", "_", bad)[:60]
                            (rd / f"{slug}-{fname}").write_bytes(text.encode("utf-8", "surrogatepass"))
                shutil.rmtree(d, ignore_errors=True)
                if per_surface >= 1000 and (i + 1) % 1000 == 0:   # long campaigns show progress
                    print(f"  {name}: {i + 1}/{per_surface} tried, {counts['tracebacks']} tracebacks, "
                          f"{counts['hangs']} hangs, {counts['silent_wrong']} silent-wrong", file=sys.stderr,
                          flush=True)
            counts["kinds"] = kinds
            results[name] = counts
            print(f"{name:20s} tried {counts['tried']:5d}  accepted {counts['accepted']:5d}  refused "
                  f"{counts['refused']:5d}  tracebacks {counts['tracebacks']:4d}  hangs {counts['hangs']:3d}  "
                  f"half-written {counts['half_written']:3d}  silent-wrong {counts['silent_wrong']:3d}  "
                  f"cpu {counts['cpu']:6.1f} s", flush=True)
            for k, v in kinds.items():
                print(f"    {v['count']:4d} x {k}", flush=True)
        return results
    finally:
        shutil.rmtree(work, ignore_errors=True)


def report(results: dict, per_surface: int, seed: int | str, timeout: float, wall: float,
           how: str = "") -> str:
    import subprocess
    from _report import machine_line
    try:
        rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                             timeout=10).stdout.strip()
    except OSError:
        rev = ""
    lines = ["## Fuzzing the inputs (`benchmarks/fuzz.py`)", "",
             f"`python benchmarks/fuzz.py --per-surface {per_surface} --seed {seed} --timeout {timeout:g}`"
             f"{f' at commit {rev}' if rev else ''}: mutated valid inputs of every command-line input surface, "
             f"each run in a forked child with a {timeout:g} s bound{how}. {machine_line()} Wall time {wall:.0f} s, "
             f"CPU per surface in the table.", "",
             "| surface | tried | accepted | refused (one line) | tracebacks | hangs | half-written | "
             "silent-wrong | CPU s |", "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for name, c in results.items():
        sw = str(c["silent_wrong"]) if name == "nc-program" else "n/a"
        lines.append(f"| {name} | {c['tried']} | {c['accepted']} | {c['refused']} | {c['tracebacks']} | "
                     f"{c['hangs']} | {c['half_written']} | {sw} | {c['cpu']:.1f} |")
    lines += ["", "Failure causes (count x first failing site):", ""]
    any_kind = False
    for name, c in results.items():
        for k, v in c["kinds"].items():
            any_kind = True
            lines.append(f"- {name}: {v['count']} x {k}")
    if not any_kind:
        lines.append("- none")
    lines += ["", "silent-wrong is judged where an oracle exists: `compensate` with zero errors must give the "
              "program back byte for byte. `accepted` inputs of the other surfaces are not judged."]
    if per_surface < 10000:
        lines[-1] += (" Counts of a short campaign are a sample, not the acceptance run of issue 15 "
                      "(10,000 per surface).")
    return "\n".join(lines)


# surfaces by CPU cost of a 300-input run (the first campaign), to balance the workers
COST = {"diagnose-csv": 33, "geometric-set": 17, "iso230-2-run": 10.5}


def _worker(args):
    a, names = args
    return campaign(a.per_surface, a.seed, a.timeout, names, a.repro_dir, a.memory_mb, a.show)


def parallel_campaign(a, names: list[str] | None) -> dict:
    """Run the campaign in `a.jobs` forked processes over disjoint sets of surfaces."""
    import multiprocessing
    if names is None:
        with tempfile.TemporaryDirectory() as t:
            names = list(make_seeds(Path(t)))
    groups: list[list[str]] = [[] for _ in range(min(a.jobs, len(names)))]
    load = [0.0] * len(groups)
    for n in sorted(names, key=lambda n: -COST.get(n, 8.0)):   # greedy: heaviest first
        k = load.index(min(load))
        groups[k].append(n)
        load[k] += COST.get(n, 8.0)
    with multiprocessing.get_context("fork").Pool(len(groups)) as pool:
        parts = pool.map(_worker, [(a, g) for g in groups])
    res = {}
    for n in names:  # keep the table order of the surfaces
        for p in parts:
            if n in p:
                res[n] = p[n]
    return res


def merge(files: list[Path], no_docs: bool) -> int:
    """Report the union of campaigns saved with --json (for runs split by hand)."""
    res, metas = {}, []
    for f in files:
        d = json.loads(f.read_text())
        metas.append(d["meta"])
        res.update(d["results"])
    per = {m["per_surface"] for m in metas}
    seeds = ", ".join(str(m["seed"]) for m in metas)
    text = report(res, min(per), seeds, max(m["timeout"] for m in metas), max(m["wall"] for m in metas),
                  f"; {len(files)} runs in parallel over disjoint surfaces (seeds {seeds})")
    print(text)
    if not no_docs:
        from _report import update_section
        update_section("fuzz", text)
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--per-surface", type=int, default=40, help="inputs per surface (default 40)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--timeout", type=float, default=20.0, help="wall-time bound per input, s (default 20)")
    ap.add_argument("--memory-mb", type=int, default=3000, help="address-space limit per input (MB)")
    ap.add_argument("--surfaces", help="comma-separated subset")
    ap.add_argument("--repro-dir", type=Path, help="keep the first input of every failure cause here")
    ap.add_argument("--json", type=Path, help="write the counts and examples as JSON")
    ap.add_argument("--show", action="store_true", help="print the last stderr line of every input")
    ap.add_argument("--no-docs", action="store_true", help="do not update docs/benchmarks.md")
    ap.add_argument("--jobs", type=int, default=1,
                    help="worker processes; surfaces are split between them (results do not depend on it)")
    ap.add_argument("--merge", type=Path, nargs="+", metavar="JSON",
                    help="do not fuzz: report the union of earlier --json outputs (disjoint surfaces)")
    a = ap.parse_args(argv)
    if a.merge:
        return merge(a.merge, a.no_docs)
    t = time.monotonic()
    names = a.surfaces.split(",") if a.surfaces else None
    if a.jobs > 1:
        res = parallel_campaign(a, names)
    else:
        res = campaign(a.per_surface, a.seed, a.timeout, names, a.repro_dir, a.memory_mb, a.show)
    wall = time.monotonic() - t
    if a.json:
        meta = dict(per_surface=a.per_surface, seed=a.seed, timeout=a.timeout, wall=wall, jobs=a.jobs)
        a.json.write_text(json.dumps({"meta": meta, "results": res}, indent=1, default=str))
    text = report(res, a.per_surface, a.seed, a.timeout, wall,
                  f", {a.jobs} worker processes" if a.jobs > 1 else "")
    print(text)
    if not a.no_docs and not a.surfaces:
        from _report import update_section
        update_section("fuzz", text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
