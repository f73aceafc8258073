/* Fixed-substep classical Runge-Kutta (RK4) over one communication step, input held constant. */
#ifndef KOOPBRIDGE_RK4_H
#define KOOPBRIDGE_RK4_H

#include <math.h>

/* Largest state dimension of the project's FMUs. */
#define RK4_MAX_STATES 8

/* Right-hand side dx/dt = f(x, u; p). */
typedef void (*rk4_rhs)(const double *p, const double *u, const double *x, double *dx);

/* Advances x (n states) by `h_total` seconds in ceil(h_total / h_max) equal RK4 substeps with u
 * held constant (zero-order hold). Returns the number of substeps taken, 0 when h_total is 0, or
 * -1 when the arguments are invalid or the state became non-finite (x is then left unchanged). */
static int rk4_advance(rk4_rhs f, const double *p, const double *u, double *x, int n,
                       double h_total, double h_max) {
    double y[RK4_MAX_STATES], k1[RK4_MAX_STATES], k2[RK4_MAX_STATES], k3[RK4_MAX_STATES],
        k4[RK4_MAX_STATES], tmp[RK4_MAX_STATES];
    int i, s, steps;
    double h;
    if (n <= 0 || n > RK4_MAX_STATES || !(h_total >= 0.0) || !(h_max > 0.0) || !isfinite(h_total))
        return -1;
    if (h_total == 0.0) return 0;
    steps = (int)ceil(h_total / h_max - 1e-9);
    if (steps < 1) steps = 1;
    h = h_total / steps;
    for (i = 0; i < n; i++) y[i] = x[i];
    for (s = 0; s < steps; s++) {
        f(p, u, y, k1);
        for (i = 0; i < n; i++) tmp[i] = y[i] + 0.5 * h * k1[i];
        f(p, u, tmp, k2);
        for (i = 0; i < n; i++) tmp[i] = y[i] + 0.5 * h * k2[i];
        f(p, u, tmp, k3);
        for (i = 0; i < n; i++) tmp[i] = y[i] + h * k3[i];
        f(p, u, tmp, k4);
        for (i = 0; i < n; i++) y[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
    }
    for (i = 0; i < n; i++)
        if (!isfinite(y[i])) return -1;
    for (i = 0; i < n; i++) x[i] = y[i];
    return steps;
}

#endif
