/* The double pendulum of SPEC.md as an FMI 3.0 co-simulation FMU with an internal RK4 integrator.
 *
 * theta'' = M(theta)^-1 (tau - C(theta, theta') - G(theta)), tau = (u1, u2), no damping.
 *
 * Value references (must match double_pendulum.xml):
 *   0 time; 1 theta1, 2 theta2, 3 omega1, 4 omega2 (outputs); 5 u1, 6 u2 (inputs);
 *   7 theta1_0, 8 theta2_0, 9 omega1_0, 10 omega2_0 (initial state);
 *   11 g, 12 l1, 13 l2, 14 m1, 15 m2 (physical parameters); 16 max_substep (largest RK4 substep). */

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi3Functions.h"
#include "rk4.h"

#define TOKEN "{0f4b9a8e-5c21-4d6f-b3e0-2a7d91c4e5f8}"
#define NVARS 17
#define VR_TIME 0
#define VR_X 1       /* theta1, theta2, omega1, omega2 */
#define VR_U 5       /* u1, u2 */
#define VR_X0 7      /* theta1_0 .. omega2_0 */
#define VR_P 11      /* g, l1, l2, m1, m2 */
#define VR_MAX_SUBSTEP 16

typedef enum { ST_INSTANTIATED, ST_INIT, ST_STEP, ST_TERMINATED, ST_ERROR } Phase;

typedef struct {
    double v[NVARS]; /* every variable, indexed by value reference (v[0] is the time) */
    Phase phase;
    char *name;
    fmi3InstanceEnvironment env;
    fmi3LogMessageCallback log;
} Instance;

static const double DEFAULTS[NVARS] = {0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 9.8, 1, 1, 1, 1, 1e-3};

static fmi3Status fail(Instance *c, const char *msg) {
    if (c && c->log) c->log(c->env, fmi3Error, "logStatusError", msg);
    return fmi3Error;
}

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
    for (i = 0; i < 4; i++) c->v[VR_X + i] = c->v[VR_X0 + i];
}

/* ---- common functions ---- */
const char *fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance c, fmi3Boolean on, size_t n, const fmi3String cats[]) {
    (void)on;
    (void)n;
    (void)cats;
    return c ? fmi3OK : fmi3Error;
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String name, fmi3String token, fmi3String res, fmi3Boolean visible,
                                          fmi3Boolean logging, fmi3InstanceEnvironment env,
                                          fmi3LogMessageCallback log) {
    (void)name;
    (void)token;
    (void)res;
    (void)visible;
    (void)logging;
    if (log) log(env, fmi3Error, "logStatusError", "double_pendulum supports co-simulation only");
    return NULL;
}

fmi3Instance fmi3InstantiateScheduledExecution(fmi3String name, fmi3String token, fmi3String res,
                                               fmi3Boolean visible, fmi3Boolean logging,
                                               fmi3InstanceEnvironment env, fmi3LogMessageCallback log,
                                               fmi3ClockUpdateCallback cu, fmi3LockPreemptionCallback lp,
                                               fmi3UnlockPreemptionCallback up) {
    (void)name;
    (void)token;
    (void)res;
    (void)visible;
    (void)logging;
    (void)cu;
    (void)lp;
    (void)up;
    if (log) log(env, fmi3Error, "logStatusError", "double_pendulum supports co-simulation only");
    return NULL;
}

fmi3Instance fmi3InstantiateCoSimulation(fmi3String name, fmi3String token, fmi3String res, fmi3Boolean visible,
                                         fmi3Boolean logging, fmi3Boolean eventModeUsed,
                                         fmi3Boolean earlyReturnAllowed, const fmi3ValueReference req[],
                                         size_t nreq, fmi3InstanceEnvironment env, fmi3LogMessageCallback log,
                                         fmi3IntermediateUpdateCallback iu) {
    Instance *c;
    (void)res;
    (void)visible;
    (void)logging;
    (void)eventModeUsed;
    (void)earlyReturnAllowed;
    (void)req;
    (void)nreq;
    (void)iu;
    if (!name) return NULL;
    if (!token || strcmp(token, TOKEN) != 0) {
        if (log) log(env, fmi3Error, "logStatusError", "instantiation token mismatch");
        return NULL;
    }
    c = (Instance *)calloc(1, sizeof(Instance));
    if (!c) return NULL;
    c->name = strdup(name);
    c->env = env;
    c->log = log;
    c->phase = ST_INSTANTIATED;
    memcpy(c->v, DEFAULTS, sizeof DEFAULTS);
    return c;
}

void fmi3FreeInstance(fmi3Instance inst) {
    Instance *c = (Instance *)inst;
    if (!c) return;
    free(c->name);
    free(c);
}

fmi3Status fmi3EnterInitializationMode(fmi3Instance inst, fmi3Boolean tolDef, fmi3Float64 tol, fmi3Float64 start,
                                       fmi3Boolean stopDef, fmi3Float64 stop) {
    Instance *c = (Instance *)inst;
    (void)tolDef;
    (void)tol;
    (void)stopDef;
    (void)stop;
    if (!c || c->phase != ST_INSTANTIATED) return fail(c, "fmi3EnterInitializationMode: wrong state");
    c->v[VR_TIME] = start;
    c->phase = ST_INIT;
    return fmi3OK;
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance inst) {
    Instance *c = (Instance *)inst;
    int i;
    if (!c || c->phase != ST_INIT) return fail(c, "fmi3ExitInitializationMode: wrong state");
    for (i = 1; i < 5; i++)
        if (!(c->v[VR_P + i] > 0.0)) return fail(c, "parameters l1, l2, m1, m2 must be positive");
    if (!(c->v[VR_MAX_SUBSTEP] > 0.0)) return fail(c, "parameter max_substep must be positive");
    load_initial_state(c);
    c->phase = ST_STEP;
    return fmi3OK;
}

fmi3Status fmi3EnterEventMode(fmi3Instance c) { return fail((Instance *)c, "fmi3EnterEventMode: no events"); }

fmi3Status fmi3Terminate(fmi3Instance inst) {
    Instance *c = (Instance *)inst;
    if (!c) return fmi3Error;
    c->phase = ST_TERMINATED;
    return fmi3OK;
}

fmi3Status fmi3Reset(fmi3Instance inst) {
    Instance *c = (Instance *)inst;
    if (!c) return fmi3Error;
    memcpy(c->v, DEFAULTS, sizeof DEFAULTS);
    c->phase = ST_INSTANTIATED;
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
        values[i] = c->v[vr[i]];
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
        c->v[r] = values[i];
    }
    return fmi3OK;
}

/* Getters and setters of types the model does not have: an error unless called for no variable. */
#define NO_VARS(fn, T)                                                                                  \
    fmi3Status fn(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, T values[], size_t nv) { \
        (void)vr;                                                                                       \
        (void)values;                                                                                   \
        (void)nv;                                                                                       \
        return nvr == 0 ? fmi3OK : fail((Instance *)c, #fn ": the model has no such variables");        \
    }
NO_VARS(fmi3GetFloat32, fmi3Float32)
NO_VARS(fmi3GetInt8, fmi3Int8)
NO_VARS(fmi3GetUInt8, fmi3UInt8)
NO_VARS(fmi3GetInt16, fmi3Int16)
NO_VARS(fmi3GetUInt16, fmi3UInt16)
NO_VARS(fmi3GetInt32, fmi3Int32)
NO_VARS(fmi3GetUInt32, fmi3UInt32)
NO_VARS(fmi3GetInt64, fmi3Int64)
NO_VARS(fmi3GetUInt64, fmi3UInt64)
NO_VARS(fmi3GetBoolean, fmi3Boolean)
NO_VARS(fmi3GetString, fmi3String)
NO_VARS(fmi3SetFloat32, const fmi3Float32)
NO_VARS(fmi3SetInt8, const fmi3Int8)
NO_VARS(fmi3SetUInt8, const fmi3UInt8)
NO_VARS(fmi3SetInt16, const fmi3Int16)
NO_VARS(fmi3SetUInt16, const fmi3UInt16)
NO_VARS(fmi3SetInt32, const fmi3Int32)
NO_VARS(fmi3SetUInt32, const fmi3UInt32)
NO_VARS(fmi3SetInt64, const fmi3Int64)
NO_VARS(fmi3SetUInt64, const fmi3UInt64)
NO_VARS(fmi3SetBoolean, const fmi3Boolean)
NO_VARS(fmi3SetString, const fmi3String)

/* Functions of capabilities the FMU does not declare: they report an error and change nothing. */
#define UNSUPPORTED(fn, ...)                                                \
    fmi3Status fn(fmi3Instance inst_, __VA_ARGS__) {                        \
        return fail((Instance *)inst_, #fn " is not supported by this FMU"); \
    }
#define UNUSED_ARGS_BEGIN _Pragma("GCC diagnostic push") _Pragma("GCC diagnostic ignored \"-Wunused-parameter\"")
#define UNUSED_ARGS_END _Pragma("GCC diagnostic pop")

UNUSED_ARGS_BEGIN
UNSUPPORTED(fmi3GetBinary, const fmi3ValueReference vr[], size_t nvr, size_t sizes[], fmi3Binary v[], size_t nv)
UNSUPPORTED(fmi3SetBinary, const fmi3ValueReference vr[], size_t nvr, const size_t sizes[], const fmi3Binary v[],
            size_t nv)
UNSUPPORTED(fmi3GetClock, const fmi3ValueReference vr[], size_t nvr, fmi3Clock v[])
UNSUPPORTED(fmi3SetClock, const fmi3ValueReference vr[], size_t nvr, const fmi3Clock v[])
UNSUPPORTED(fmi3GetNumberOfVariableDependencies, fmi3ValueReference vr, size_t *n)
UNSUPPORTED(fmi3GetVariableDependencies, fmi3ValueReference d, size_t ed[], fmi3ValueReference ind[], size_t ei[],
            fmi3DependencyKind k[], size_t n)
UNSUPPORTED(fmi3GetFMUState, fmi3FMUState *s)
UNSUPPORTED(fmi3SetFMUState, fmi3FMUState s)
UNSUPPORTED(fmi3FreeFMUState, fmi3FMUState *s)
UNSUPPORTED(fmi3SerializedFMUStateSize, fmi3FMUState s, size_t *n)
UNSUPPORTED(fmi3SerializeFMUState, fmi3FMUState s, fmi3Byte b[], size_t n)
UNSUPPORTED(fmi3DeserializeFMUState, const fmi3Byte b[], size_t n, fmi3FMUState *s)
UNSUPPORTED(fmi3GetDirectionalDerivative, const fmi3ValueReference u[], size_t nu, const fmi3ValueReference k[],
            size_t nk, const fmi3Float64 seed[], size_t ns, fmi3Float64 sens[], size_t nsens)
UNSUPPORTED(fmi3GetAdjointDerivative, const fmi3ValueReference u[], size_t nu, const fmi3ValueReference k[],
            size_t nk, const fmi3Float64 seed[], size_t ns, fmi3Float64 sens[], size_t nsens)
UNSUPPORTED(fmi3GetIntervalDecimal, const fmi3ValueReference vr[], size_t n, fmi3Float64 iv[],
            fmi3IntervalQualifier q[])
UNSUPPORTED(fmi3GetIntervalFraction, const fmi3ValueReference vr[], size_t n, fmi3UInt64 c[], fmi3UInt64 r[],
            fmi3IntervalQualifier q[])
UNSUPPORTED(fmi3GetShiftDecimal, const fmi3ValueReference vr[], size_t n, fmi3Float64 s[])
UNSUPPORTED(fmi3GetShiftFraction, const fmi3ValueReference vr[], size_t n, fmi3UInt64 c[], fmi3UInt64 r[])
UNSUPPORTED(fmi3SetIntervalDecimal, const fmi3ValueReference vr[], size_t n, const fmi3Float64 iv[])
UNSUPPORTED(fmi3SetIntervalFraction, const fmi3ValueReference vr[], size_t n, const fmi3UInt64 c[],
            const fmi3UInt64 r[])
UNSUPPORTED(fmi3SetShiftDecimal, const fmi3ValueReference vr[], size_t n, const fmi3Float64 s[])
UNSUPPORTED(fmi3SetShiftFraction, const fmi3ValueReference vr[], size_t n, const fmi3UInt64 c[],
            const fmi3UInt64 r[])
UNSUPPORTED(fmi3UpdateDiscreteStates, fmi3Boolean *a, fmi3Boolean *b, fmi3Boolean *d, fmi3Boolean *e,
            fmi3Boolean *f, fmi3Float64 *t)
UNSUPPORTED(fmi3CompletedIntegratorStep, fmi3Boolean no, fmi3Boolean *e, fmi3Boolean *t)
UNSUPPORTED(fmi3SetTime, fmi3Float64 t)
UNSUPPORTED(fmi3SetContinuousStates, const fmi3Float64 x[], size_t n)
UNSUPPORTED(fmi3GetContinuousStateDerivatives, fmi3Float64 dx[], size_t n)
UNSUPPORTED(fmi3GetEventIndicators, fmi3Float64 e[], size_t n)
UNSUPPORTED(fmi3GetContinuousStates, fmi3Float64 x[], size_t n)
UNSUPPORTED(fmi3GetNominalsOfContinuousStates, fmi3Float64 x[], size_t n)
UNSUPPORTED(fmi3GetNumberOfEventIndicators, size_t *n)
UNSUPPORTED(fmi3GetNumberOfContinuousStates, size_t *n)
UNSUPPORTED(fmi3GetOutputDerivatives, const fmi3ValueReference vr[], size_t nvr, const fmi3Int32 o[],
            fmi3Float64 v[], size_t nv)
UNSUPPORTED(fmi3ActivateModelPartition, fmi3ValueReference clock, fmi3Float64 t)
UNUSED_ARGS_END

fmi3Status fmi3EnterConfigurationMode(fmi3Instance c) { return fail((Instance *)c, "no structural parameters"); }
fmi3Status fmi3ExitConfigurationMode(fmi3Instance c) { return fail((Instance *)c, "no structural parameters"); }
fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance c) { return fail((Instance *)c, "no discrete states"); }
fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance c) { return fail((Instance *)c, "co-simulation only"); }

/* ---- co-simulation ---- */
fmi3Status fmi3EnterStepMode(fmi3Instance c) {
    return fail((Instance *)c, "fmi3EnterStepMode: event mode is not used by this FMU");
}

fmi3Status fmi3DoStep(fmi3Instance inst, fmi3Float64 t, fmi3Float64 h, fmi3Boolean noSetPrior,
                      fmi3Boolean *eventNeeded, fmi3Boolean *terminate, fmi3Boolean *earlyReturn,
                      fmi3Float64 *lastTime) {
    Instance *c = (Instance *)inst;
    double x[4], u[2];
    char msg[200];
    int i;
    (void)noSetPrior;
    if (eventNeeded) *eventNeeded = fmi3False;
    if (terminate) *terminate = fmi3False;
    if (earlyReturn) *earlyReturn = fmi3False;
    if (!c || c->phase != ST_STEP) return fail(c, "fmi3DoStep: the FMU is not initialized");
    if (lastTime) *lastTime = c->v[VR_TIME];
    if (!(h > 0.0)) return fail(c, "fmi3DoStep: communication step size must be positive");
    if (fabs(t - c->v[VR_TIME]) > 1e-9 * (1.0 + fabs(t))) {
        snprintf(msg, sizeof msg, "fmi3DoStep: communication point %.17g does not match the FMU time %.17g", t,
                 c->v[VR_TIME]);
        return fail(c, msg);
    }
    for (i = 0; i < 4; i++) x[i] = c->v[VR_X + i];
    for (i = 0; i < 2; i++) u[i] = c->v[VR_U + i];
    if (!isfinite(u[0]) || !isfinite(u[1])) {
        c->phase = ST_ERROR;
        return fail(c, "fmi3DoStep: an input is not finite");
    }
    if (rk4_advance(rhs, &c->v[VR_P], u, x, 4, h, c->v[VR_MAX_SUBSTEP]) < 0) {
        c->phase = ST_ERROR;
        return fail(c, "fmi3DoStep: the state became non-finite");
    }
    for (i = 0; i < 4; i++) c->v[VR_X + i] = x[i];
    c->v[VR_TIME] = t + h;
    if (lastTime) *lastTime = c->v[VR_TIME];
    return fmi3OK;
}
