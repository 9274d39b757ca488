"""CadQuery CAM plugin: calibration features, the papers' parts, toolpaths, a Fanuc-style post
and a virtual machining check (docs/cad.md).

Modules: ``layout`` (part layouts, closed-form geometry), ``features`` (CadQuery features and
parts; importing it registers the Workplane methods and loads cadquery), ``export`` (STEP/STL),
``toolpath`` (toolpaths, machine axes through mtcomp.kinematics), ``post`` (G-code), ``check``
(virtual machining and probing), ``cli`` (``mtcomp cad``).  Importing this package stays light:
cadquery is imported only by ``features`` and inside the export functions.
"""
