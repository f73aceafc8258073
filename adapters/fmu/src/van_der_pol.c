/* The Van der Pol oscillator as an FMI 2.0 co-simulation FMU with no inputs (an autonomous
 * system) and an internal RK4 integrator.
 *
 * x0' = x1,  x1' = mu (1 - x0^2) x1 - x0
 *
 * Value references (must match van_der_pol.xml):
 *   0 x0, 1 x1 (outputs); 2 x0_start, 3 x1_start (initial state); 4 mu; 5 max_substep
 *   (largest RK4 substep, s). */

#include "rk4.h"

#define FMU_NAME "van_der_pol"
#define GUID "{e94b8aed-b190-4606-9702-506848f7ecf3}"
#define NVARS 6
#define VR_X0 0
#define VR_X1 1
#define VR_X0_START 2
#define VR_X1_START 3
#define VR_MU 4
#define VR_MAX_SUBSTEP 5
#define N_STATES 2 /* the states, also the outputs: value references 0, 1 */
#define VR_STATE_START VR_X0_START /* the first parameter: the initial state */

typedef struct {
    double v[NVARS]; /* every variable, indexed by value reference */
} Model;

#include "fmi2_common.h"
#include "fmi2_real_model.h"

static const double DEFAULTS[NVARS] = {2.0, 0.0, 2.0, 0.0, 1.0, 1e-3};

static void rhs(const double *p, const double *u, const double *x, double *dx) {
    const double mu = p[0];
    (void)u; /* autonomous: no inputs */
    dx[0] = x[1];
    dx[1] = mu * (1.0 - x[0] * x[0]) * x[1] - x[0];
}

static void model_reset(Instance *c) { memcpy(c->m.v, DEFAULTS, sizeof DEFAULTS); }

static fmi2Status model_initialize(Instance *c) {
    if (!isfinite(c->m.v[VR_MU])) return fail(c, "parameter mu must be finite");
    if (!(c->m.v[VR_MAX_SUBSTEP] > 0.0)) return fail(c, "parameter max_substep must be positive");
    if (!isfinite(c->m.v[VR_X0_START]) || !isfinite(c->m.v[VR_X1_START]))
        return fail(c, "initial state x0_start, x1_start must be finite");
    load_initial_state(c);
    return fmi2OK;
}

/* ---- co-simulation ---- */
fmi2Status fmi2DoStep(fmi2Component comp, fmi2Real t, fmi2Real h, fmi2Boolean noSetPrior) {
    Instance *c = (Instance *)comp;
    double p[1], x[2];
    (void)noSetPrior;
    if (do_step_checks(c, h) != fmi2OK || check_communication_point(c, t) != fmi2OK) return fmi2Error;
    p[0] = c->m.v[VR_MU];
    x[0] = c->m.v[VR_X0];
    x[1] = c->m.v[VR_X1];
    if (rk4_advance(rhs, p, NULL, x, 2, h, c->m.v[VR_MAX_SUBSTEP]) < 0) {
        c->phase = ST_ERROR;
        return fail(c, "fmi2DoStep: the state became non-finite");
    }
    c->m.v[VR_X0] = x[0];
    c->m.v[VR_X1] = x[1];
    c->time = t + h;
    return fmi2OK;
}
