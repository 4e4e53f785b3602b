/*
 * FMI 3.0 Co-Simulation glue of an exported controller: the ODE FMUs' FMI 3.0 glue
 * (../ode/ode_glue3.c) wrapped around the FMI 2.0 controller glue ctrl_glue.c, with the
 * Int32 variable fdi_mode forwarded to fmi2GetInteger / fmi2SetInteger.
 */
#define GLUE3_INNER "ctrl_glue.c"
#define GLUE3_MODEL_NAME CTRL_MODEL_NAME
#define GLUE3_NX 0
#define GLUE3_INT32_AS_FMI2_INTEGER 1
#include "ode_glue3.c"
