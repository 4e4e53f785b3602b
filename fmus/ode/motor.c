/*
 * DCMotor: nonlinear DC motor test plant for the generic ODE FMU glue (ode_model.h).
 *
 *   J omega' = k_eff K i - b omega - c omega |omega| - tau_load
 *   L i'     = V - (R + R_extra) i - k_eff K omega
 *
 * states x = (omega [rad/s], i [A]), inputs u = (V [V], tau_load [N.m]),
 * parameters p = (J, b, c, R, L, K, k_eff, R_extra), outputs y = (omega_meas, omega_out,
 * i_meas) = (omega, omega, i). The faults: k_eff < 1 weakens the torque/back-emf constant,
 * R_extra > 0 adds winding resistance. With the nominal values (J = 0.01, b = 5e-4,
 * c = 3e-5, R = 1, L = 0.05, K = 0.05) and V = 12, tau_load = 0 the stationary point is
 * omega = 100 rad/s, i = 7 A, where the quadratic drag (2 c omega = 6e-3) dominates the
 * viscous friction (b = 5e-4) in the linearisation.
 */
#include <math.h>

#include "ode_model.h"

const int ODE_NX = 2, ODE_NU = 2, ODE_NP = 8, ODE_NY = 3;
const int ODE_HAS_JACOBIAN = 1;

enum { P_J, P_B, P_C, P_R, P_L, P_K, P_KEFF, P_REXTRA };
enum { U_V, U_TAU };

void ode_rhs(double t, const double *x, const double *u, const double *p, double *dx) {
    (void)t;
    const double w = x[0], i = x[1], kK = p[P_KEFF] * p[P_K];
    dx[0] = (kK * i - p[P_B] * w - p[P_C] * w * fabs(w) - u[U_TAU]) / p[P_J];
    dx[1] = (u[U_V] - (p[P_R] + p[P_REXTRA]) * i - kK * w) / p[P_L];
}

void ode_out(double t, const double *x, const double *u, const double *p, double *y) {
    (void)t, (void)u, (void)p;
    y[0] = x[0]; /* omega_meas */
    y[1] = x[0]; /* omega_out  */
    y[2] = x[1]; /* i_meas     */
}

void ode_jac(double t, const double *x, const double *u, const double *p, double *dfdx,
             double *dfdu, double *dgdx, double *dgdu) {
    (void)t, (void)u, (void)dgdu;
    const double w = x[0], kK = p[P_KEFF] * p[P_K], J = p[P_J], L = p[P_L];
    dfdx[0] = (-p[P_B] - 2.0 * p[P_C] * fabs(w)) / J; /* d(w|w|)/dw = 2|w| */
    dfdx[1] = kK / J;
    dfdx[2] = -kK / L;
    dfdx[3] = -(p[P_R] + p[P_REXTRA]) / L;
    dfdu[0 * 2 + U_V] = 0.0;
    dfdu[0 * 2 + U_TAU] = -1.0 / J;
    dfdu[1 * 2 + U_V] = 1.0 / L;
    dfdu[1 * 2 + U_TAU] = 0.0;
    dgdx[0 * 2 + 0] = 1.0;
    dgdx[1 * 2 + 0] = 1.0;
    dgdx[2 * 2 + 1] = 1.0;
}
