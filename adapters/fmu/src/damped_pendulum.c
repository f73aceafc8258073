/* The damped pendulum of SPEC.md as an FMI 2.0 co-simulation FMU with an internal RK4 integrator.
 *
 * theta'' = -(g/l) sin(theta) - (b l / m) theta' + cos(theta) u / (m l)
 *
 * Value references (must match damped_pendulum.xml):
 *   0 theta, 1 omega (outputs); 2 u (input); 3 theta0, 4 omega0 (initial state);
 *   5 g, 6 l, 7 m, 8 b (physical parameters); 9 max_substep (largest RK4 substep, s). */

#include "rk4.h"

#define FMU_NAME "damped_pendulum"
#define GUID "{6c1f3a52-3d0e-4c8e-9a57-8d0b2e6f41a7}"
#define NVARS 10
#define VR_THETA 0
#define VR_OMEGA 1
#define VR_U 2
#define VR_THETA0 3
#define VR_OMEGA0 4
#define VR_G 5
#define VR_L 6
#define VR_M 7
#define VR_B 8
#define VR_MAX_SUBSTEP 9
#define N_STATES 2 /* the states, also the outputs: value references 0, 1 */
#define VR_STATE_START VR_THETA0 /* the first parameter: the initial state */

typedef struct {
    double v[NVARS]; /* every variable, indexed by value reference */
} Model;

#include "fmi2_common.h"
#include "fmi2_real_model.h"

static const double DEFAULTS[NVARS] = {0.0, 0.0, 0.0, 0.0, 0.0, 9.8, 1.0, 1.0, 1.0, 1e-3};

static void rhs(const double *p, const double *u, const double *x, double *dx) {
    const double g = p[0], l = p[1], m = p[2], b = p[3];
    dx[0] = x[1];
    dx[1] = -(g / l) * sin(x[0]) - (b * l / m) * x[1] + cos(x[0]) * u[0] / (m * l);
}

static void model_reset(Instance *c) { memcpy(c->m.v, DEFAULTS, sizeof DEFAULTS); }

static fmi2Status model_initialize(Instance *c) {
    if (!(c->m.v[VR_L] > 0.0) || !(c->m.v[VR_M] > 0.0)) return fail(c, "parameters l and m must be positive");
    if (!(c->m.v[VR_MAX_SUBSTEP] > 0.0)) return fail(c, "parameter max_substep must be positive");
    load_initial_state(c);
    return fmi2OK;
}

/* ---- co-simulation ---- */
fmi2Status fmi2DoStep(fmi2Component comp, fmi2Real t, fmi2Real h, fmi2Boolean noSetPrior) {
    Instance *c = (Instance *)comp;
    double p[4], x[2], u[1];
    (void)noSetPrior;
    if (do_step_checks(c, h) != fmi2OK || check_communication_point(c, t) != fmi2OK) return fmi2Error;
    p[0] = c->m.v[VR_G];
    p[1] = c->m.v[VR_L];
    p[2] = c->m.v[VR_M];
    p[3] = c->m.v[VR_B];
    x[0] = c->m.v[VR_THETA];
    x[1] = c->m.v[VR_OMEGA];
    u[0] = c->m.v[VR_U];
    if (!isfinite(u[0])) {
        c->phase = ST_ERROR;
        return fail(c, "fmi2DoStep: input u is not finite");
    }
    if (rk4_advance(rhs, p, u, x, 2, h, c->m.v[VR_MAX_SUBSTEP]) < 0) {
        c->phase = ST_ERROR;
        return fail(c, "fmi2DoStep: the state became non-finite");
    }
    c->m.v[VR_THETA] = x[0];
    c->m.v[VR_OMEGA] = x[1];
    c->time = t + h;
    return fmi2OK;
}
