(Exported by FreeCAD)
(Post Processor: linuxcnc_post)
(Output Time:2026-01-01 00:00:00)
(begin preamble)
G17 G54 G40 G49 G80 G90
G21
(begin operation: Fixture)
(machine units: mm/min)
G54
(finish operation: Fixture)
(begin operation: Profile)
(machine units: mm/min)
(Profile)
M3 S1000
G0 Z15.000
G0 X12.000 Y0.000
G0 Z5.000
G1 X12.000 Y0.000 Z-1.000 F100.000
G2 X0.000 Y12.000 Z-1.000 I-12.000 J0.000 F300.000
G2 X-12.000 Y0.000 Z-1.000 I0.000 J-12.000 F300.000
G2 X0.000 Y-12.000 Z-1.000 I12.000 J0.000 F300.000
G2 X12.000 Y0.000 Z-1.000 I0.000 J12.000 F300.000
G2 X12.000 Y0.000 Z-2.000 I-12.000 J0.000 F300.000
G0 Z15.000
(finish operation: Profile)
(begin postamble)
M05
G17 G54 G90 G80 G40
M2
