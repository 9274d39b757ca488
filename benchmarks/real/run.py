"""Run `mtcomp diagnose` on every case of the real-recordings corpus and score it against the
truth files: the named effect set per output and the held-out error ratio.

    python benchmarks/real/run.py --corpus CORPUS [--split dev|heldout|all] [--source NAME ...]
                                  [--json OUT.json] [--docs] [--timeout S]

CORPUS (or MTCOMP_REAL_CORPUS) holds <source>/<case>/{sim.csv, rec.csv, truth.toml}, written by
the converters beside this file.  The diagnosis run is the `mtcomp` of the interpreter that runs
this script (the installed code, not a copy).  Which sources are development and which are
held out is fixed in manifest.toml beside this file; nothing may be tuned on held-out sources,
and their figures are reported apart.

A case is right when, for every output, the set of named effects is the expected one (or one of
its alternatives), plus at most effects the truth calls acceptable; and when the held-out RMS of
all outputs together is at least halved (RMS after / before <= 0.5) or, where the truth is
"nothing beyond the instrument's resolution", nothing is named (but acceptable extras); where
the truth lists outputs as `unexplained` (no effect of the library describes them), nothing may
be named on them and the result must list them as unexplained.  `--docs` writes the per-source
table into docs/diagnose.md between the markers of the section "Real corpus".
"""
from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
import tomllib
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent
DOCS = ROOT / "docs" / "diagnose.md"
BEGIN, END = "<!-- BEGIN real-corpus -->", "<!-- END real-corpus -->"


def manifest() -> dict:
    """source -> {split, family, licence, converter, url} from manifest.toml."""
    with open(HERE / "manifest.toml", "rb") as f:
        return tomllib.load(f)["sources"]


def cases(corpus: Path, sources=None) -> list:
    """(source, case, folder, truth) of every case in the corpus, sorted."""
    out = []
    for t in sorted(Path(corpus).glob("*/*/truth.toml")):
        src, case = t.parent.parent.name, t.parent.name
        if sources and src not in sources:
            continue
        with open(t, "rb") as f:
            out.append((src, case, t.parent, tomllib.load(f)))
    return out


def mtcomp() -> list:
    """The command of the installed CLI beside this interpreter."""
    exe = Path(sys.executable).parent / "mtcomp"
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "mtcomp"]


def diagnose(folder: Path, truth: dict, timeout: float) -> dict:
    """The JSON result of `mtcomp diagnose` on a case (or {"error": ...})."""
    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "res.json"
        cmd = mtcomp() + ["diagnose", "--sim", str(folder / "sim.csv"), "--rec", str(folder / "rec.csv"),
                          "--json", str(out), "--quiet"] + list(truth.get("args", []))
        t0 = time.perf_counter()
        try:
            p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            return {"error": f"timeout after {timeout:.0f} s", "seconds": timeout}
        dt = time.perf_counter() - t0
        if p.returncode != 0 or not out.exists():
            msg = (p.stderr or p.stdout).strip().splitlines()
            return {"error": short_error(msg[-1]) if msg else f"exit {p.returncode}", "seconds": dt}
        res = json.loads(out.read_text())
        res["seconds"] = dt
        return res


def short_error(msg: str) -> str:
    """The CLI's error line without the corpus folder (it names only the case's files)."""
    return re.sub(r"\S*/((?:sim|rec)\.csv)", r"\1", msg).replace("mtcomp diagnose: error: ", "")


def named_per_output(res: dict) -> dict:
    """output -> set of effect names named on it."""
    out = {o: set() for o in res.get("outputs", [])}
    for e in res.get("effects", []):
        for o in str(e["output"]).split(","):
            out.setdefault(o.strip(), set()).add(e["name"])
    return out


def set_ok(named: set, expected: list, acceptable: list, alternatives: list) -> bool:
    """The named set is the expected set (or an alternative) plus only acceptable extras."""
    for want in [expected] + list(alternatives):
        want = set(want)
        if want <= named and named - want <= set(acceptable):
            return True
    return False


def score(truth: dict, res: dict) -> dict:
    """Per-case verdict: effect sets per output, held-out ratio, success."""
    if "error" in res:
        return {"ok": False, "set_ok": False, "ratio": float("nan"), "named": {}, "error": res["error"],
                "seconds": res.get("seconds", 0.0), "unexplained": []}
    named = named_per_output(res)
    exp, acc = truth.get("expected", {}), truth.get("acceptable", {})
    alt = truth.get("alternatives", {})
    unexp_truth = set(truth.get("unexplained", []))
    unexp_res = {u["output"] for u in res.get("unexplained", [])}
    per = {}
    for o, want in exp.items():
        if o in unexp_truth:
            # no effect of the library fits: nothing named (but acceptable extras) and the
            # output said to be unexplained
            per[o] = named.get(o, set()) <= set(acc.get(o, [])) and o in unexp_res
        else:
            per[o] = set_ok(named.get(o, set()), want, acc.get(o, []), alt.get(o, []))
    # an effect named on an output the truth does not list is wrong
    extra = {o: n for o, n in named.items() if o not in exp and n}
    sets = all(per.values()) and not extra and bool(exp)
    b = sum(v ** 2 for v in res["fit"]["holdout_rms_before"].values())
    a = sum(v ** 2 for v in res["fit"]["holdout_rms_after"].values())
    ratio = (a / b) ** 0.5 if b > 0 else float("nan")
    nothing = all(not v for v in exp.values())
    if unexp_truth:
        ok = sets
    elif nothing:
        # nothing beyond the instrument: nothing named but what the truth calls acceptable
        ok = all(n <= set(acc.get(o, [])) for o, n in named.items())
    else:
        ok = sets and ratio <= 0.5
    return {"ok": bool(ok), "set_ok": bool(sets), "ratio": ratio,
            "named": {o: sorted(n) for o, n in named.items()}, "error": "",
            "seconds": res["seconds"], "unexplained": [u["output"] for u in res.get("unexplained", [])]}


def fmt_effects(d: dict, unexplained=()) -> str:
    parts = [f"{o}: {', '.join(v) if v else ('unexplained' if o in unexplained else '-')}"
             for o, v in d.items()]
    return "; ".join(parts) if parts else "-"


def case_table(rows) -> str:
    lines = ["| split | source | case | expected | named | held-out after/before | right set | right |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['split']} | {r['source']} | {r['case']} | "
                     f"{fmt_effects(r['expected'], r.get('truth_unexplained', []))} | "
                     + (f"error: {short_error(r['error'])}" if r["error"] else fmt_effects(r["named"]))
                     + f" | {r['ratio']:.2f} | {'yes' if r['set_ok'] else 'no'} | {'yes' if r['ok'] else 'no'} |")
    return "\n".join(lines)


def source_table(rows, man) -> str:
    lines = ["| source | split | licence | cases | expected effects | evidence | right set | right (set and halved) |",
             "|---|---|---|---|---|---|---|---|"]
    by = {}
    for r in rows:
        by.setdefault(r["source"], []).append(r)
    for s, rs in by.items():
        effects = sorted({e for r in rs for v in r["expected"].values() for e in v})
        n_unexp = sum(bool(r.get("truth_unexplained")) for r in rs)
        n_none = sum(not any(r["expected"].values()) and not r.get("truth_unexplained") for r in rs)
        if n_none:
            effects.append(f"nothing beyond resolution ({n_none} case{'s' * (n_none > 1)})")
        if n_unexp:
            effects.append(f"unexplained, no library effect ({n_unexp} case{'s' * (n_unexp > 1)})")
        m = man.get(s, {})
        lines.append(f"| {s} | {m.get('split', '?')} | {m.get('licence', rs[0]['licence'])} | {len(rs)} | "
                     f"{', '.join(effects)} | {m.get('evidence', '')} | "
                     f"{sum(r['set_ok'] for r in rs)}/{len(rs)} | {sum(r['ok'] for r in rs)}/{len(rs)} |")
    return "\n".join(lines)


def summary(rows) -> str:
    out = []
    for split in ("dev", "heldout"):
        rs = [r for r in rows if r["split"] == split]
        if not rs:
            continue
        srcs = sorted({r["source"] for r in rs})
        out.append(f"- {split}: {len(rs)} cases from {len(srcs)} sources; right effect set "
                   f"{sum(r['set_ok'] for r in rs)}/{len(rs)}, right set and held-out error at least "
                   f"halved (where nothing is expected: nothing named; where no library effect fits: nothing "
                   f"named and the output flagged unexplained) "
                   f"**{sum(r['ok'] for r in rs)}/{len(rs)}** "
                   f"({100 * sum(r['ok'] for r in rs) / len(rs):.0f} %)")
    return "\n".join(out)


def write_docs(text: str) -> None:
    doc = DOCS.read_text()
    if BEGIN in doc:
        head, rest = doc.split(BEGIN, 1)
        tail = rest.split(END, 1)[1]
        doc = head + BEGIN + "\n" + text + "\n" + END + tail
    else:
        doc = doc.rstrip("\n") + "\n\n" + BEGIN + "\n" + text + "\n" + END + "\n"
    tmp = DOCS.with_suffix(".tmp")
    tmp.write_text(doc)
    tmp.replace(DOCS)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description="Diagnose the real-recordings corpus and score it.")
    p.add_argument("--corpus", default=os.environ.get("MTCOMP_REAL_CORPUS"))
    p.add_argument("--split", choices=("dev", "heldout", "all"), default="all")
    p.add_argument("--source", action="append", help="only these sources (repeatable)")
    p.add_argument("--json", help="write every case's verdict to this file")
    p.add_argument("--docs", action="store_true", help="write the tables into docs/diagnose.md")
    p.add_argument("--timeout", type=float, default=900.0, help="seconds per case")
    p.add_argument("--from-json", help="rebuild the tables from the verdicts of an earlier run "
                                       "(--json) instead of diagnosing again")
    a = p.parse_args(argv)
    if not a.corpus:
        p.error("give --corpus or set MTCOMP_REAL_CORPUS")
    man = manifest()
    todo = []
    for src, case, folder, truth in cases(Path(a.corpus), a.source):
        if src not in man:
            print(f"[skip] {src}/{case}: source not in manifest.toml (assign dev|heldout first)", flush=True)
            continue
        if a.split != "all" and man[src]["split"] != a.split:
            continue
        todo.append((src, case, folder, truth))
    rows = []
    t0 = time.perf_counter()
    if a.from_json:
        old = {(r["source"], r["case"]): r for r in json.loads(Path(a.from_json).read_text())}
        for src, case, folder, truth in todo:
            if (src, case) in old:
                r = old[(src, case)]
                r.update(split=man[src]["split"], expected=truth.get("expected", {}),
                         truth_unexplained=truth.get("unexplained", []))
                rows.append(r)
        todo = []
    for i, (src, case, folder, truth) in enumerate(todo, 1):
        res = diagnose(folder, truth, a.timeout)
        v = score(truth, res)
        row = {"source": src, "case": case, "split": man[src]["split"], "licence": truth.get("licence", ""),
               "expected": truth.get("expected", {}), "truth_unexplained": truth.get("unexplained", []), **v}
        rows.append(row)
        print(f"[{i}/{len(todo)} {time.perf_counter() - t0:6.0f} s] {man[src]['split']:7s} {src}/{case}: "
              f"named {fmt_effects(v['named']) if not v['error'] else 'ERROR ' + v['error']} | "
              f"expected {fmt_effects(row['expected'])} | ratio {v['ratio']:.2f} | "
              f"{'RIGHT' if v['ok'] else 'wrong'} ({v['seconds']:.1f} s)", flush=True)
    text = "\n\n".join([summary(rows), source_table(rows, man), case_table(rows)])
    print("\n" + text)
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=1, default=str))
    if a.docs:
        write_docs(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
