"""The whole chain on a synthetic machine in one call: runs -> tables -> volumetric error ->
compensation.  For demonstrations and acceptance checks; each step is the library function
that a user calls on real data."""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from ..errors import ErrorSet
from ..machine import Machine, load_machine
from . import comptables, iso230_2, synthetic, tables, volumetric

__all__ = ["StudyResult", "synthetic_study"]


@dataclass(frozen=True)
class StudyResult:
    """Results of `synthetic_study`; figures in mm (summary in µm)."""
    machine: Machine
    truth: ErrorSet
    measurements: tables.MeasurementSet
    build: tables.BuildResult
    truth_map: volumetric.VolumetricMap
    built_map: volumetric.VolumetricMap
    compensation: comptables.CompensationReport
    lattice: comptables.LatticeTable
    files: dict

    def figures(self) -> dict:
        s = self.truth_map.stats()
        d = volumetric.compare(self.truth_map, self.built_map)
        out = {"volumetric_max": s["max"], "volumetric_rms": s["rms"],
               "first_order_minus_exact_max": s.get("first_order_diff_max", float("nan")),
               "tables_minus_truth_max": d["max"], "tables_minus_truth_rms": d["rms"]}
        for k, (mx, rms) in self.compensation.figures.items():
            out[f"residual_max[{k}]"] = mx
            out[f"residual_rms[{k}]"] = rms
        return out

    def summary(self) -> str:
        f = self.figures()
        lines = [f"Synthetic study on {self.machine.name}: {len(self.measurements.runs)} "
                 "simulated interferometer runs",
                 f"  volumetric error: max {f['volumetric_max'] * 1e3:.2f} µm, RMS "
                 f"{f['volumetric_rms'] * 1e3:.2f} µm",
                 f"  first-order model minus exact: max {f['first_order_minus_exact_max'] * 1e6:.2f} nm",
                 f"  tables from the runs minus truth (volumetric): max "
                 f"{f['tables_minus_truth_max'] * 1e3:.4f} µm, RMS {f['tables_minus_truth_rms'] * 1e3:.4f} µm"]
        lines.append(self.compensation.summary().rstrip())
        for k, p in self.files.items():
            lines.append(f"  {k}: {p}")
        return "\n".join(lines) + "\n"


def synthetic_study(machine: Machine | str = "vmc-moving-column", seed: int = 0,
                    noise: tables.Noise | None = tables.Noise(0.1e-3, 0.2e-3, 0.2e-6, 2e-3),
                    run_step: float = 2.5, map_step: float = 25.0, lattice_step: float = 25.0,
                    n_random: int = 2000, out_dir: str | os.PathLike | None = None) -> StudyResult:
    """Simulate the runs of a synthetic machine (noise None: noise-free), build the tables,
    map the volumetric error and compensate it; with out_dir, write the measurement set, the
    ISO 230-2 report of the X run, the built errors, the map PNG and the compensation tables."""
    from ..errors import save_errors

    machine = load_machine(machine)
    syn = synthetic.make_synthetic(machine, seed=seed, min_wavelength=250.0, run_step=run_step)
    truth = syn.errors()
    mset = tables.simulate_runs(machine, truth, tables.Setup.typical(seed), noise or tables.Noise(),
                                step=run_step, seed=seed)
    build = tables.build_tables(machine, mset)
    grid = volumetric.volume_grid(machine, map_step)
    tmap = volumetric.error_map(machine, truth, grid)
    bmap = volumetric.error_map(machine, build.errors, grid)
    lat = comptables.lattice_table(machine, build.errors, lattice_step)
    rep = comptables.compensation_report(machine, truth, build.errors, lat, n_random=n_random,
                                         step=map_step, seed=seed)
    files: dict = {}
    if out_dir is not None:
        d = Path(out_dir)
        files["measurement set"] = tables.save_measurement_set(mset, d / "runs.toml")
        first = machine.axes[0].name
        files["ISO 230-2 report"] = iso230_2.write_report(build.iso[first],
                                                          d / f"iso230-2_{first}")["text"]
        files["errors"] = save_errors(build.errors, d / "geometric.toml")
        volumetric.plot_map(tmap, d / "volumetric.png")
        files["volumetric map"] = d / "volumetric.png"
        from .._io import atomic_write
        files["lattice"] = atomic_write(d / "lattice.csv", lat.to_csv())
        files["ISO 230-1 tables"] = comptables.write_iso_tables(build.geometric, d, "comp")[0].parent
    return StudyResult(machine, truth, mset, build, tmap, bmap, rep, lat, files)
