/* The double pendulum of SPEC.md as an FMI 3.0 co-simulation FMU with an internal RK4 integrator.
 *
 * theta'' = M(theta)^-1 (tau - C(theta, theta') - G(theta)), tau = (u1, u2), no damping.
 *
 * Value references (must match double_pendulum.xml):
 *   0 time; 1 theta1, 2 theta2, 3 omega1, 4 omega2 (outputs); 5 u1, 6 u2 (inputs);
 *   7 theta1_0, 8 theta2_0, 9 omega1_0, 10 omega2_0 (initial state);
 *   11 g, 12 l1, 13 l2, 14 m1, 15 m2 (physical parameters); 16 max_substep (largest RK4 substep). */

#include "rk4.h"

#define FMU_NAME "double_pendulum"
#define TOKEN "{0f4b9a8e-5c21-4d6f-b3e0-2a7d91c4e5f8}"
#define NVARS 17
#define VR_TIME 0
#define VR_X 1       /* theta1, theta2, omega1, omega2 */
#define VR_U 5       /* u1, u2 */
#define VR_X0 7      /* theta1_0 .. omega2_0 */
#define VR_P 11      /* g, l1, l2, m1, m2 */
#define VR_MAX_SUBSTEP 16

typedef struct {
    double v[NVARS]; /* every variable, indexed by value reference (v[0] is the time) */
} Model;
#define MODEL_TIME(c) ((c)->m.v[VR_TIME])

#include "fmi3_common.h"

static const double DEFAULTS[NVARS] = {0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 9.8, 1, 1, 1, 1, 1e-3};

static void rhs(const double *p, const double *u, const double *x, double *dx) {
    const double g = p[0], l1 = p[1], l2 = p[2], m1 = p[3], m2 = p[4];
    const double t1 = x[0], t2 = x[1], w1 = x[2], w2 = x[3];
    const double c2 = cos(t2), s2 = sin(t2);
    const double M11 = m1 * l1 * l1 + m2 * (l1 * l1 + 2 * l1 * l2 * c2 + l2 * l2);
    const double M12 = m2 * (l1 * l2 * c2 + l2 * l2);
    const double M22 = m2 * l2 * l2;
    const double C1 = -m2 * l1 * l2 * s2 * (2 * w1 * w2 + w2 * w2);
    const double C2 = m2 * l1 * l2 * w1 * w1 * s2;
    const double G1 = (m1 + m2) * l1 * g * cos(t1) + m2 * l2 * g * cos(t1 + t2);
    const double G2 = m2 * l2 * g * cos(t1 + t2);
    const double r1 = u[0] - C1 - G1, r2 = u[1] - C2 - G2;
    const double det = M11 * M22 - M12 * M12;
    dx[0] = w1;
    dx[1] = w2;
    dx[2] = (M22 * r1 - M12 * r2) / det;
    dx[3] = (-M12 * r1 + M11 * r2) / det;
}

static void load_initial_state(Instance *c) {
    int i;
    for (i = 0; i < 4; i++) c->m.v[VR_X + i] = c->m.v[VR_X0 + i];
}

static void model_reset(Instance *c) { memcpy(c->m.v, DEFAULTS, sizeof DEFAULTS); }

static fmi3Status model_initialize(Instance *c) {
    int i;
    for (i = 1; i < 5; i++)
        if (!(c->m.v[VR_P + i] > 0.0)) return fail(c, "parameters l1, l2, m1, m2 must be positive");
    if (!(c->m.v[VR_MAX_SUBSTEP] > 0.0)) return fail(c, "parameter max_substep must be positive");
    load_initial_state(c);
    return fmi3OK;
}

fmi3Status fmi3GetFloat64(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr, fmi3Float64 values[],
                          size_t nv) {
    Instance *c = (Instance *)inst;
    size_t i;
    if (!c) return fmi3Error;
    if (nv != nvr) return fail(c, "fmi3GetFloat64: nValues must equal nValueReferences (scalars only)");
    if (c->phase == ST_INIT) load_initial_state(c); /* outputs are calculated from the initial state */
    for (i = 0; i < nvr; i++) {
        if (vr[i] >= NVARS) return fail(c, "fmi3GetFloat64: unknown value reference");
        values[i] = c->m.v[vr[i]];
    }
    return fmi3OK;
}

fmi3Status fmi3SetFloat64(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr, const fmi3Float64 values[],
                          size_t nv) {
    Instance *c = (Instance *)inst;
    size_t i;
    if (!c) return fmi3Error;
    if (nv != nvr) return fail(c, "fmi3SetFloat64: nValues must equal nValueReferences (scalars only)");
    for (i = 0; i < nvr; i++) {
        const fmi3ValueReference r = vr[i];
        if (r >= NVARS) return fail(c, "fmi3SetFloat64: unknown value reference");
        if (r < VR_U) return fail(c, "fmi3SetFloat64: time and outputs cannot be set");
        if (r >= VR_X0 && c->phase != ST_INSTANTIATED && c->phase != ST_INIT)
            return fail(c, "fmi3SetFloat64: parameters can only be set before initialization ends");
        c->m.v[r] = values[i];
    }
    return fmi3OK;
}

/* The model has Float64 variables only. */
FMI3_NO_VARS(fmi3GetFloat32, fmi3Float32)
FMI3_NO_VARS(fmi3GetInt8, fmi3Int8)
FMI3_NO_VARS(fmi3GetUInt8, fmi3UInt8)
FMI3_NO_VARS(fmi3GetInt16, fmi3Int16)
FMI3_NO_VARS(fmi3GetUInt16, fmi3UInt16)
FMI3_NO_VARS(fmi3GetInt32, fmi3Int32)
FMI3_NO_VARS(fmi3GetUInt32, fmi3UInt32)
FMI3_NO_VARS(fmi3GetInt64, fmi3Int64)
FMI3_NO_VARS(fmi3GetUInt64, fmi3UInt64)
FMI3_NO_VARS(fmi3GetBoolean, fmi3Boolean)
FMI3_NO_VARS(fmi3GetString, fmi3String)
FMI3_NO_VARS(fmi3SetFloat32, const fmi3Float32)
FMI3_NO_VARS(fmi3SetInt8, const fmi3Int8)
FMI3_NO_VARS(fmi3SetUInt8, const fmi3UInt8)
FMI3_NO_VARS(fmi3SetInt16, const fmi3Int16)
FMI3_NO_VARS(fmi3SetUInt16, const fmi3UInt16)
FMI3_NO_VARS(fmi3SetInt32, const fmi3Int32)
FMI3_NO_VARS(fmi3SetUInt32, const fmi3UInt32)
FMI3_NO_VARS(fmi3SetInt64, const fmi3Int64)
FMI3_NO_VARS(fmi3SetUInt64, const fmi3UInt64)
FMI3_NO_VARS(fmi3SetBoolean, const fmi3Boolean)
FMI3_NO_VARS(fmi3SetString, const fmi3String)
UNUSED_ARGS_BEGIN
FMI3_UNSUPPORTED(fmi3GetBinary, const fmi3ValueReference vr[], size_t nvr, size_t sizes[], fmi3Binary v[], size_t nv)
FMI3_UNSUPPORTED(fmi3SetBinary, const fmi3ValueReference vr[], size_t nvr, const size_t sizes[], const fmi3Binary v[],
                 size_t nv)
UNUSED_ARGS_END

fmi3Status fmi3EnterConfigurationMode(fmi3Instance c) { return fail((Instance *)c, "no structural parameters"); }
fmi3Status fmi3ExitConfigurationMode(fmi3Instance c) { return fail((Instance *)c, "no structural parameters"); }

/* ---- co-simulation ---- */
fmi3Status fmi3DoStep(fmi3Instance inst, fmi3Float64 t, fmi3Float64 h, fmi3Boolean noSetPrior,
                      fmi3Boolean *eventNeeded, fmi3Boolean *terminate, fmi3Boolean *earlyReturn,
                      fmi3Float64 *lastTime) {
    Instance *c = (Instance *)inst;
    double x[4], u[2];
    char msg[200];
    int i;
    (void)noSetPrior;
    if (do_step_checks(c, eventNeeded, terminate, earlyReturn) != fmi3OK) return fmi3Error;
    if (lastTime) *lastTime = c->m.v[VR_TIME];
    if (!(h > 0.0)) return fail(c, "fmi3DoStep: communication step size must be positive");
    if (fabs(t - c->m.v[VR_TIME]) > 1e-9 * (1.0 + fabs(t))) {
        snprintf(msg, sizeof msg, "fmi3DoStep: communication point %.17g does not match the FMU time %.17g", t,
                 c->m.v[VR_TIME]);
        return fail(c, msg);
    }
    for (i = 0; i < 4; i++) x[i] = c->m.v[VR_X + i];
    for (i = 0; i < 2; i++) u[i] = c->m.v[VR_U + i];
    if (!isfinite(u[0]) || !isfinite(u[1])) {
        c->phase = ST_ERROR;
        return fail(c, "fmi3DoStep: an input is not finite");
    }
    if (rk4_advance(rhs, &c->m.v[VR_P], u, x, 4, h, c->m.v[VR_MAX_SUBSTEP]) < 0) {
        c->phase = ST_ERROR;
        return fail(c, "fmi3DoStep: the state became non-finite");
    }
    for (i = 0; i < 4; i++) c->m.v[VR_X + i] = x[i];
    c->m.v[VR_TIME] = t + h;
    if (lastTime) *lastTime = c->m.v[VR_TIME];
    return fmi3OK;
}
