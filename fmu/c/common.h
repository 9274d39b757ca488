/* Value references and resource handling shared by the compensator and the machine FMU.
 * mtcomp/fmu/build.py writes modelDescription.xml with the same numbers (docs/fmu.md). */
#ifndef MTCOMP_COMMON_H
#define MTCOMP_COMMON_H

#include "model.h"

/* Real value references common to both models */
#define VR_CMD 0          /* 0..8   axis commands (inputs), chain order, mm or deg */
#define VR_TOOL 20        /* 20..22 tool setting offset, mm */
#define VR_WP_T 23        /* 23..25 workpiece translation, mm */
#define VR_WP_A 26        /* 26..28 workpiece angles a, b, c, deg */
#define VR_LOC 40         /* 40 + 6*axis + k: E{X,Y,Z}0{axis} mm (k < 3), E{A,B,C}0{axis} rad */
#define VR_LOC_END (VR_LOC + 6 * MTK_MAX_AXES)
/* String value references */
#define SVR_TABLES 0      /* geometric tables: "X:tables/X.csv;Z:tables/Z.csv" (resource paths) */
#define MACHINE_RESOURCE "machine.txt"  /* machine description in the resources folder */
#define START_RESOURCE "start.txt"      /* parameter start values in the resources folder */

/* Range checks of the parameters shared by both models (limits documented in docs/fmu.md). */
#define MAX_TOOL_OFFSET 50.0      /* mm */
#define MAX_WP_TRANSLATION 500.0  /* mm */
#define MAX_WP_ANGLE 30.0         /* deg */
#define MAX_LOC_LINEAR 5.0        /* mm */
#define MAX_LOC_ANGLE 0.05        /* rad */

int common_real_kind(unsigned vr, int n_axes);
void common_vr_name(unsigned vr, const mtk_model *m, char *buf, size_t cap);
fmi2Status common_check_real(Instance *inst, unsigned vr, double value);
void common_defaults(Instance *inst);
void common_start_values(Instance *inst);
/* (Re)load the machine description and the geometric tables from the resources. */
fmi2Status common_load(Instance *inst);
void common_errors(const Instance *inst, mtk_errors *e);
fmi2Status check_range(Instance *inst, const char *what, double value, double lo, double hi);

#endif
