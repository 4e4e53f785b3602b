/*
 * Contract between a nonlinear ODE model written in plain C and the generic FMI 2.0 glue
 * (ode_glue.c). The model
 *
 *     x' = f(t, x, u, p),        y = g(t, x, u, p)
 *
 * with NX states x, NU Real inputs u, NP Real parameters p and NY Real outputs y is one C
 * file that includes this header and defines everything declared under "provided by the
 * model file". The builder (ftc_verify/plants/ode_fmu.py) compiles it together with
 * ode_glue.c and a generated ode_spec.h (names, start values, GUID; see below) into one
 * shared library that serves Model Exchange and Co-Simulation.
 *
 * Value references (consecutive Real variables, in this order; NX, NU, NP, NY from the
 * spec, checked against ODE_NX.. at instantiation):
 *
 *     1              .. NX            states x            local, continuous, initial exact
 *     NX+1           .. 2NX           derivatives der(x)  local, continuous, calculated
 *     2NX+1          .. 2NX+NU        inputs u            input, continuous
 *     2NX+NU+1       .. 2NX+NU+NP     parameters p        parameter, tunable or fixed
 *     2NX+NU+NP+1    .. 2NX+NU+NP+NY  outputs y           output, continuous, calculated
 *
 * All arrays are dense, 0-based, row-major; the glue never passes NULL (arrays of length
 * zero are valid pointers that must not be read or written).
 */
#ifndef ODE_MODEL_H
#define ODE_MODEL_H

/* ---- provided by the model file ---------------------------------------------------- */

/* Numbers of states, Real inputs, Real parameters and Real outputs. */
extern const int ODE_NX, ODE_NU, ODE_NP, ODE_NY;

/* 1 when ode_jac below is exact and provided, 0 otherwise (then ode_jac may be absent). */
extern const int ODE_HAS_JACOBIAN;

/* dx[0..NX-1] = f(t, x, u, p). Must not keep pointers; called many times per step. */
void ode_rhs(double t, const double *x, const double *u, const double *p, double *dx);

/* y[0..NY-1] = g(t, x, u, p). */
void ode_out(double t, const double *x, const double *u, const double *p, double *y);

/* Exact Jacobians, row-major: dfdx[i*NX+j] = d f_i / d x_j (NX x NX), dfdu (NX x NU),
 * dgdx (NY x NX), dgdu (NY x NU). The glue zeroes all four before the call, so a model
 * may write only the non-zero entries. Needed only when ODE_HAS_JACOBIAN is 1. */
void ode_jac(double t, const double *x, const double *u, const double *p,
             double *dfdx, double *dfdu, double *dgdx, double *dgdu);

/* ---- provided by the builder: ode_spec.h (included by ode_glue.c only) ----------------
 *
 *   #define ODE_SPEC_MODEL_NAME   "Name"      model identifier
 *   #define ODE_SPEC_GUID         "{...}"     must equal the modelDescription's guid
 *   #define ODE_SPEC_NX/NU/NP/NY  n           must equal ODE_NX.. of the model file
 *   #define ODE_SPEC_HAS_JACOBIAN 0 or 1      must equal ODE_HAS_JACOBIAN
 *   static const double ODE_SPEC_X_START[], ODE_SPEC_U_START[], ODE_SPEC_P_START[];
 *   static const int    ODE_SPEC_P_TUNABLE[];
 *   static const char *const ODE_SPEC_X_NAMES[], ODE_SPEC_U_NAMES[], ODE_SPEC_P_NAMES[],
 *                            ODE_SPEC_Y_NAMES[];
 *
 * (arrays of a zero dimension hold one dummy element).
 */

#endif /* ODE_MODEL_H */
