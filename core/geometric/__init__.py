"""mtcomp.geometric: geometric errors of linear axes from laser-interferometer measurements.

Modules (imported on demand, none is loaded here): iso230_2 (ISO 230-2 evaluation), tables
(component tables from runs, Abbe removal), first_order (paper 004's formulas and the general
first-order model), volumetric (tool-tip error over the work volume), comptables (corrected
commands, 3-D lattice and ISO 230-1-named tables), synthetic (a machine with known errors),
study (the whole chain in one call), cli (`mtcomp geometric ...`).  See docs/geometric.md.
"""
