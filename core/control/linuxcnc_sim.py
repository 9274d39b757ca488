"""A headless LinuxCNC simulation (uspace, no display) that loads exported joint compensation
files, runs a program and samples the joints with HAL -- the real motion module checking how
it reads mtcomp's files.

`run_sim` writes a configuration (INI, HAL file, tool table, the program and a driver), starts
`linuxcnc` with the driver as its DISPLAY program -- the driver runs under the system Python,
whose `linuxcnc` module ships with LinuxCNC, switches the machine on, runs the program in auto
mode and records `joint.N.pos-cmd`, `motor-pos-cmd`, `vel-cmd` and `backlash-corr` every servo
period with the `sampler` component and `halsampler` -- and returns
the samples when LinuxCNC has shut down (it does so when the driver exits; a timeout kills it).
Motor feedback is looped back (no hardware); every joint is homed where it stands (0).
`model_corrections` gives mtcomp's model of the same commands: the trims of the comp files,
linear between nominal positions, held beyond them, forward trim while the joint moves up and
reverse trim while it moves down (src/emc/motion/control.c compute_screw_comp).
"""
from __future__ import annotations

import os
import shutil
import signal
import subprocess
import tempfile
from pathlib import Path

import numpy as np

__all__ = ["available", "run_sim", "model_corrections", "merge_ini", "PINS"]

# sampled per joint: pos-cmd (mm), then x SCALE: motor-pos-cmd - pos-cmd, vel-cmd, backlash-corr
# (the sampler takes at most 21 pins: 4 per joint for up to 5 joints)
PINS = ("pos-cmd", "motor-minus-pos", "vel-cmd", "backlash-corr")
SCALE = 1e6
SYSTEM_PYTHON = "/usr/bin/python3"

_DRIVER = r'''#!/usr/bin/python3
import os, signal, subprocess, sys, time
import linuxcnc
ini = linuxcnc.ini(sys.argv[sys.argv.index("-ini") + 1])
out, prog = ini.find("MTCOMP", "SAMPLES"), ini.find("MTCOMP", "PROGRAM")
s, c = linuxcnc.stat(), linuxcnc.command()
def wait(cond, t=20.0):
    end = time.time() + t
    while time.time() < end:
        s.poll()
        if cond():
            return True
        time.sleep(0.02)
    raise SystemExit("driver: timed out")
wait(lambda: s.task_state == linuxcnc.STATE_ESTOP)
c.state(linuxcnc.STATE_ESTOP_RESET); wait(lambda: s.task_state == linuxcnc.STATE_ESTOP_RESET)
c.state(linuxcnc.STATE_ON); wait(lambda: s.task_state == linuxcnc.STATE_ON)
c.mode(linuxcnc.MODE_MANUAL); wait(lambda: s.task_mode == linuxcnc.MODE_MANUAL)
n = int(ini.find("KINS", "JOINTS"))
c.home(-1)          # HOME_SEARCH_VEL = 0: every joint is homed where it stands
wait(lambda: all(s.homed[:n]))
c.mode(linuxcnc.MODE_AUTO); wait(lambda: s.task_mode == linuxcnc.MODE_AUTO)
c.program_open(prog); wait(lambda: s.file != "")
with open(out, "w") as fh:
    hs = subprocess.Popen(["halsampler", "-c", "0"], stdout=fh)
    time.sleep(0.2)
    c.auto(linuxcnc.AUTO_RUN, 0)
    wait(lambda: s.interp_state != linuxcnc.INTERP_IDLE, 10.0)
    wait(lambda: s.interp_state == linuxcnc.INTERP_IDLE and s.inpos, 120.0)
    time.sleep(0.2)
    hs.send_signal(signal.SIGINT)
    try:
        hs.wait(5)
    except subprocess.TimeoutExpired:
        hs.kill()
c.state(linuxcnc.STATE_OFF)
'''


def available() -> bool:
    """linuxcnc, halsampler and the system Python's linuxcnc module are here."""
    if not (shutil.which("linuxcnc") and shutil.which("halsampler") and os.path.exists(SYSTEM_PYTHON)):
        return False
    r = subprocess.run([SYSTEM_PYTHON, "-c", "import linuxcnc"], capture_output=True)
    return r.returncode == 0


def _ini(letters: str, comp: dict, limits: dict, samples: Path, program: Path, driver: Path,
         kins: str = "trivkins") -> str:
    j = len(letters)
    lines = ["[EMC]", "VERSION = 1.1", "MACHINE = mtcomp-comp-check", "DEBUG = 0",
             "[DISPLAY]", f"DISPLAY = {driver}",
             "[MTCOMP]", f"SAMPLES = {samples}", f"PROGRAM = {program}",
             "[TASK]", "TASK = milltask", "CYCLE_TIME = 0.010",
             "[RS274NGC]", "PARAMETER_FILE = sim.var",
             "[EMCMOT]", "EMCMOT = motmod", "COMM_TIMEOUT = 1.0", "SERVO_PERIOD = 1000000",
             "[EMCIO]", "EMCIO = io", "CYCLE_TIME = 0.100", "TOOL_TABLE = sim.tbl",
             "[HAL]", "HALFILE = sim.hal",
             "[TRAJ]", f"COORDINATES = {' '.join(letters)}", "LINEAR_UNITS = mm", "ANGULAR_UNITS = degree",
             "MAX_LINEAR_VELOCITY = 1000", "DEFAULT_LINEAR_VELOCITY = 100", "NO_FORCE_HOMING = 1",
             "POSITION_FILE = position.txt",
             "[KINS]", f"KINEMATICS = {kins} coordinates={letters}", f"JOINTS = {j}"]
    for i, a in enumerate(letters):
        lo, hi = limits[a]
        common = [f"MIN_LIMIT = {lo - 1}", f"MAX_LIMIT = {hi + 1}", "MAX_VELOCITY = 1000",
                  "MAX_ACCELERATION = 4000"]
        lines += [f"[AXIS_{a}]", *common,
                  f"[JOINT_{i}]", f"TYPE = {'ANGULAR' if a in 'ABC' else 'LINEAR'}", "HOME = 0",
                  "HOME_OFFSET = 0", "HOME_SEARCH_VEL = 0", "HOME_LATCH_VEL = 0", "HOME_SEQUENCE = 0", "FERROR = 10", "MIN_FERROR = 10", *common]
        if a in comp:
            lines += [f"COMP_FILE = {comp[a]}", "COMP_FILE_TYPE = 1", "BACKLASH = 0.0"]
    return "\n".join(lines) + "\n"


def merge_ini(base: str, fragment: str) -> str:
    """`base` INI text with every key of `fragment` (e.g. the exported linuxcnc-comp.ini) set in its
    section: an existing key is replaced, a new one appended to the section (or a new section)."""
    frag: dict[str, dict[str, str]] = {}
    sect = None
    for line in fragment.splitlines():
        t = line.strip()
        if t.startswith("[") and t.endswith("]"):
            sect = t
            frag.setdefault(sect, {})
        elif sect and "=" in t and not t.startswith(("#", ";")):
            k, v = (x.strip() for x in t.split("=", 1))
            frag[sect][k] = v
    out, sect, done = [], None, set()

    def flush():
        if sect in frag:
            out.extend(f"{k} = {v}" for k, v in frag[sect].items() if (sect, k) not in done)
    for line in base.splitlines():
        t = line.strip()
        if t.startswith("[") and t.endswith("]"):
            flush()
            sect = t
        elif sect in frag and "=" in t:
            k = t.split("=", 1)[0].strip()
            if k in frag[sect]:
                line = f"{k} = {frag[sect][k]}"
                done.add((sect, k))
        out.append(line)
    flush()
    seen = {ln.strip() for ln in base.splitlines()}
    for sct, kv in frag.items():
        if sct not in seen:
            out += [sct, *(f"{k} = {v}" for k, v in kv.items())]
    return "\n".join(out) + "\n"


def _hal(n: int, extra: str = "") -> str:
    """Motion, loopback feedback, and the sampler.  halsampler prints 6 decimals: every pin
    but pos-cmd is sampled times SCALE (scale / sum2 components), so the trims are recorded to
    1e-12 mm and the velocity's sign survives at a standstill's edge."""
    cfg = "f" * (len(PINS) * n)
    lines = ["loadrt [KINS]KINEMATICS",
             "loadrt [EMCMOT]EMCMOT servo_period_nsec=[EMCMOT]SERVO_PERIOD num_joints=[KINS]JOINTS",
             f"loadrt scale count={2 * n}", f"loadrt sum2 count={n}",
             f"loadrt sampler depth=20000 cfg={cfg}",
             "addf motion-command-handler servo-thread", "addf motion-controller servo-thread"]
    lines += [f"addf scale.{k} servo-thread" for k in range(2 * n)]
    lines += [f"addf sum2.{j} servo-thread" for j in range(n)]
    lines += [ln for ln in extra.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    lines += ["addf sampler.0 servo-thread",
              "net estop-loop iocontrol.0.user-enable-out => iocontrol.0.emc-enable-in"]
    k = 0
    for j in range(n):
        base = len(PINS) * j
        lines += [f"net m{j} joint.{j}.motor-pos-cmd => joint.{j}.motor-pos-fb sum2.{j}.in0",
                  f"net p{j} joint.{j}.pos-cmd => sum2.{j}.in1 sampler.0.pin.{base}",
                  f"setp sum2.{j}.gain0 {SCALE:g}", f"setp sum2.{j}.gain1 {-SCALE:g}",
                  f"net d{j} sum2.{j}.out => sampler.0.pin.{base + 1}"]
        for i, p in enumerate(("vel-cmd", "backlash-corr")):
            lines += [f"net {p}{j} joint.{j}.{p} => scale.{k}.in", f"setp scale.{k}.gain {SCALE:g}",
                      f"net {p}{j}s scale.{k}.out => sampler.0.pin.{base + 2 + i}"]
            k += 1
    return "\n".join(lines) + "\n"


def run_sim(workdir: str | os.PathLike, letters: str, comp_dir: str | os.PathLike | None, limits: dict,
            program: str, timeout: float = 180.0, kins: str = "trivkins",
            hal: str = "", ini_fragment: str | None = None) -> tuple[np.ndarray, str]:
    """Run `program` (G-code text) on a trivkins machine with joints `letters` whose comp files
    are in `comp_dir` (<letter>.comp as `mtcomp control export --control linuxcnc` writes), with
    kinematics module `kins` (its pins set by `hal`, e.g. the exported linuxcnc-kins.hal); with
    `ini_fragment` (the exported linuxcnc-comp.ini) its entries are merged into the INI, so the
    joints take their COMP_FILE, COMP_FILE_TYPE and BACKLASH from it.
    Returns (samples (T, joints, len(PINS)) in mm and mm/s, LinuxCNC's log).  Stops LinuxCNC by
    itself."""
    d = Path(workdir)
    d.mkdir(parents=True, exist_ok=True)
    comp = {}
    for a in letters:
        f = Path(comp_dir or d) / f"{a.lower()}.comp"
        if comp_dir is not None and ini_fragment is None and f.exists():
            shutil.copy(f, d / f.name)
            comp[a] = f.name
    (d / "prog.ngc").write_text(program)
    (d / "driver.py").write_text(_DRIVER.replace("/usr/bin/python3", SYSTEM_PYTHON, 1))
    (d / "driver.py").chmod(0o755)      # run as the DISPLAY program: linuxcnc puts -ini first
    (d / "sim.tbl").write_text("T1 P1 Z0 D0 ;\n")
    (d / "sim.var").write_text("")
    (d / "sim.hal").write_text(_hal(len(letters), hal))
    samples = d / "samples.txt"
    ini = d / "sim.ini"
    text = _ini(letters, comp, limits, samples, d / "prog.ngc", d / "driver.py", kins)
    if ini_fragment is not None:
        for f in Path(comp_dir).glob("*.comp"):
            shutil.copy(f, d / f.name)
        text = merge_ini(text, ini_fragment)
    ini.write_text(text)
    env = dict(os.environ)
    env.pop("DISPLAY", None)
    env["HOME"] = str(d)              # linuxcnc_print.txt / linuxcnc_debug.txt go there
    if os.geteuid() == 0:             # uspace's rtapi_app refuses root without a fallback uid
        env.setdefault("RTAPI_UID", "65534")   # setreuid(uid, 0): effective uid stays 0
        # ... and opens its FIFO with that uid as its file-system uid (setfsuid): a folder it may write
        fifo_dir = Path(tempfile.mkdtemp(prefix="mtcomp-rtapi-"))
        fifo_dir.chmod(0o777)
        env.setdefault("RTAPI_FIFO_PATH", str(fifo_dir / "rtapi_fifo"))
    proc = subprocess.Popen(["linuxcnc", str(ini)], cwd=d, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, env=env, start_new_session=True, stdin=subprocess.DEVNULL)
    try:
        log, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGTERM)
        log, _ = proc.communicate(timeout=30)
        raise RuntimeError(f"LinuxCNC did not finish in {timeout:g} s:\n{log[-2000:]}")
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        if os.geteuid() == 0:
            shutil.rmtree(fifo_dir, ignore_errors=True)
    rows = [ln.split() for ln in samples.read_text().splitlines()] if samples.exists() else []
    width = len(PINS) * len(letters)
    data = np.array([[float(x) for x in r] for r in rows if len(r) == width], float)
    if data.size:
        data = data.reshape(len(data), len(letters), len(PINS))
        data[:, :, 1:] /= SCALE
    for name in ("linuxcnc_print.txt", "linuxcnc_debug.txt"):
        if (d / name).exists():
            log += (d / name).read_text(errors="replace")
    if data.size == 0:
        raise RuntimeError(f"no samples from LinuxCNC:\n{log[-3000:]}")
    return data, log


def model_corrections(comp_text: str, pos: np.ndarray, vel: np.ndarray) -> np.ndarray:
    """mtcomp's model of LinuxCNC's screw compensation (`backlash-corr`) at joint positions `pos`
    with commanded velocities `vel`: forward trims moving up, reverse trims moving down, the last
    one kept while standing (starts at 0), linear between nominal positions, ends held."""
    t = np.array([[float(x) for x in ln.split()] for ln in comp_text.splitlines() if ln.strip()])
    fwd = np.interp(pos, t[:, 0], t[:, 1])
    rev = np.interp(pos, t[:, 0], t[:, 2])
    out = np.empty_like(pos)
    last = 0.0
    for i in range(len(pos)):
        if vel[i] > 0:
            last = fwd[i]
        elif vel[i] < 0:
            last = rev[i]
        out[i] = last
    return out
