/* The damped pendulum of SPEC.md as an FMI 2.0 co-simulation FMU with an internal RK4 integrator.
 *
 * theta'' = -(g/l) sin(theta) - (b l / m) theta' + cos(theta) u / (m l)
 *
 * Value references (must match damped_pendulum.xml):
 *   0 theta, 1 omega (outputs); 2 u (input); 3 theta0, 4 omega0 (initial state);
 *   5 g, 6 l, 7 m, 8 b (physical parameters); 9 max_substep (largest RK4 substep, s). */

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "rk4.h"

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

typedef enum { ST_INSTANTIATED, ST_INIT, ST_STEP, ST_TERMINATED, ST_ERROR } Phase;

typedef struct {
    double v[NVARS]; /* every variable, indexed by value reference */
    double time;
    Phase phase;
    char *name;
    fmi2CallbackFunctions cb;
    int logging;
} Instance;

static const double DEFAULTS[NVARS] = {0.0, 0.0, 0.0, 0.0, 0.0, 9.8, 1.0, 1.0, 1.0, 1e-3};

static void logf_(Instance *c, fmi2Status st, const char *msg) {
    if (c && c->cb.logger)
        c->cb.logger(c->cb.componentEnvironment, c->name, st, st == fmi2OK ? "logAll" : "logStatusError",
                     "%s", msg);
}

static fmi2Status fail(Instance *c, const char *msg) {
    logf_(c, fmi2Error, msg);
    return fmi2Error;
}

static void rhs(const double *p, const double *u, const double *x, double *dx) {
    const double g = p[0], l = p[1], m = p[2], b = p[3];
    dx[0] = x[1];
    dx[1] = -(g / l) * sin(x[0]) - (b * l / m) * x[1] + cos(x[0]) * u[0] / (m * l);
}

static void set_defaults(Instance *c) {
    memcpy(c->v, DEFAULTS, sizeof DEFAULTS);
    c->time = 0.0;
}

/* ---- common functions ---- */
const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cats[]) {
    (void)n;
    (void)cats;
    if (!c) return fmi2Error;
    ((Instance *)c)->logging = on;
    return fmi2OK;
}

fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String res,
                              const fmi2CallbackFunctions *cb, fmi2Boolean visible, fmi2Boolean logging) {
    Instance *c;
    (void)res;
    (void)visible;
    if (!cb || !name) return NULL;
    if (type != fmi2CoSimulation) {
        if (cb->logger)
            cb->logger(cb->componentEnvironment, name, fmi2Error, "logStatusError",
                       "damped_pendulum supports co-simulation only");
        return NULL;
    }
    if (!guid || strcmp(guid, GUID) != 0) {
        if (cb->logger)
            cb->logger(cb->componentEnvironment, name, fmi2Error, "logStatusError",
                       "GUID mismatch: expected %s", GUID);
        return NULL;
    }
    c = (Instance *)calloc(1, sizeof(Instance));
    if (!c) return NULL;
    c->name = strdup(name);
    c->cb = *cb;
    c->logging = logging;
    c->phase = ST_INSTANTIATED;
    set_defaults(c);
    return c;
}

void fmi2FreeInstance(fmi2Component comp) {
    Instance *c = (Instance *)comp;
    if (!c) return;
    free(c->name);
    free(c);
}

fmi2Status fmi2SetupExperiment(fmi2Component comp, fmi2Boolean tolDef, fmi2Real tol, fmi2Real start,
                               fmi2Boolean stopDef, fmi2Real stop) {
    Instance *c = (Instance *)comp;
    (void)tolDef;
    (void)tol;
    (void)stopDef;
    (void)stop;
    if (!c || c->phase != ST_INSTANTIATED) return fail(c, "fmi2SetupExperiment: wrong state");
    c->time = start;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component comp) {
    Instance *c = (Instance *)comp;
    if (!c || c->phase != ST_INSTANTIATED) return fail(c, "fmi2EnterInitializationMode: wrong state");
    c->phase = ST_INIT;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component comp) {
    Instance *c = (Instance *)comp;
    if (!c || c->phase != ST_INIT) return fail(c, "fmi2ExitInitializationMode: wrong state");
    if (!(c->v[VR_L] > 0.0) || !(c->v[VR_M] > 0.0))
        return fail(c, "parameters l and m must be positive");
    if (!(c->v[VR_MAX_SUBSTEP] > 0.0)) return fail(c, "parameter max_substep must be positive");
    c->v[VR_THETA] = c->v[VR_THETA0];
    c->v[VR_OMEGA] = c->v[VR_OMEGA0];
    c->phase = ST_STEP;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component comp) {
    Instance *c = (Instance *)comp;
    if (!c) return fmi2Error;
    c->phase = ST_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component comp) {
    Instance *c = (Instance *)comp;
    if (!c) return fmi2Error;
    set_defaults(c);
    c->phase = ST_INSTANTIATED;
    return fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t n, fmi2Real value[]) {
    Instance *c = (Instance *)comp;
    size_t i;
    if (!c) return fmi2Error;
    if (c->phase == ST_INIT) { /* outputs are calculated from the initial state */
        c->v[VR_THETA] = c->v[VR_THETA0];
        c->v[VR_OMEGA] = c->v[VR_OMEGA0];
    }
    for (i = 0; i < n; i++) {
        if (vr[i] >= NVARS) return fail(c, "fmi2GetReal: unknown value reference");
        value[i] = c->v[vr[i]];
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t n, const fmi2Real value[]) {
    Instance *c = (Instance *)comp;
    size_t i;
    if (!c) return fmi2Error;
    for (i = 0; i < n; i++) {
        if (vr[i] >= NVARS) return fail(c, "fmi2SetReal: unknown value reference");
        if (vr[i] == VR_THETA || vr[i] == VR_OMEGA) return fail(c, "fmi2SetReal: outputs cannot be set");
        if (vr[i] != VR_U && c->phase != ST_INSTANTIATED && c->phase != ST_INIT)
            return fail(c, "fmi2SetReal: parameters can only be set before initialization ends");
        c->v[vr[i]] = value[i];
    }
    return fmi2OK;
}

#define NO_VARS(fn, T)                                                                              \
    fmi2Status fn(fmi2Component comp, const fmi2ValueReference vr[], size_t n, T value[]) {         \
        (void)vr;                                                                                   \
        (void)value;                                                                                \
        return n == 0 ? fmi2OK : fail((Instance *)comp, #fn ": the model has no such variables");   \
    }
NO_VARS(fmi2GetInteger, fmi2Integer)
NO_VARS(fmi2GetBoolean, fmi2Boolean)
NO_VARS(fmi2GetString, fmi2String)
NO_VARS(fmi2SetInteger, const fmi2Integer)
NO_VARS(fmi2SetBoolean, const fmi2Boolean)
NO_VARS(fmi2SetString, const fmi2String)

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *s) {
    (void)s;
    return fail((Instance *)c, "fmi2GetFMUstate is not supported");
}
fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate s) {
    (void)s;
    return fail((Instance *)c, "fmi2SetFMUstate is not supported");
}
fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *s) {
    (void)s;
    return fail((Instance *)c, "fmi2FreeFMUstate is not supported");
}
fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate s, size_t *n) {
    (void)s;
    (void)n;
    return fail((Instance *)c, "FMU state serialization is not supported");
}
fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate s, fmi2Byte b[], size_t n) {
    (void)s;
    (void)b;
    (void)n;
    return fail((Instance *)c, "FMU state serialization is not supported");
}
fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte b[], size_t n, fmi2FMUstate *s) {
    (void)s;
    (void)b;
    (void)n;
    return fail((Instance *)c, "FMU state serialization is not supported");
}
fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference u[], size_t nu,
                                        const fmi2ValueReference z[], size_t nz, const fmi2Real dv[],
                                        fmi2Real dz[]) {
    (void)u;
    (void)nu;
    (void)z;
    (void)nz;
    (void)dv;
    (void)dz;
    return fail((Instance *)c, "directional derivatives are not provided");
}

/* ---- co-simulation ---- */
fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    (void)vr;
    (void)n;
    (void)order;
    (void)value;
    return fail((Instance *)c, "input derivatives are not supported");
}
fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                        const fmi2Integer order[], fmi2Real value[]) {
    (void)vr;
    (void)n;
    (void)order;
    (void)value;
    return fail((Instance *)c, "output derivatives are not supported");
}

fmi2Status fmi2DoStep(fmi2Component comp, fmi2Real t, fmi2Real h, fmi2Boolean noSetPrior) {
    Instance *c = (Instance *)comp;
    double p[4], x[2], u[1];
    char msg[200];
    (void)noSetPrior;
    if (!c || c->phase != ST_STEP) return fail(c, "fmi2DoStep: the FMU is not initialized");
    if (!(h > 0.0)) return fail(c, "fmi2DoStep: communication step size must be positive");
    if (fabs(t - c->time) > 1e-9 * (1.0 + fabs(t))) {
        snprintf(msg, sizeof msg, "fmi2DoStep: communication point %.17g does not match the FMU time %.17g",
                 t, c->time);
        return fail(c, msg);
    }
    p[0] = c->v[VR_G];
    p[1] = c->v[VR_L];
    p[2] = c->v[VR_M];
    p[3] = c->v[VR_B];
    x[0] = c->v[VR_THETA];
    x[1] = c->v[VR_OMEGA];
    u[0] = c->v[VR_U];
    if (!isfinite(u[0])) {
        c->phase = ST_ERROR;
        return fail(c, "fmi2DoStep: input u is not finite");
    }
    if (rk4_advance(rhs, p, u, x, 2, h, c->v[VR_MAX_SUBSTEP]) < 0) {
        c->phase = ST_ERROR;
        return fail(c, "fmi2DoStep: the state became non-finite");
    }
    c->v[VR_THETA] = x[0];
    c->v[VR_OMEGA] = x[1];
    c->time = t + h;
    return fmi2OK;
}

fmi2Status fmi2CancelStep(fmi2Component c) { return fail((Instance *)c, "fmi2CancelStep: steps are synchronous"); }

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *v) {
    (void)s;
    (void)v;
    return fail((Instance *)c, "fmi2GetStatus: steps are synchronous");
}
fmi2Status fmi2GetRealStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Real *v) {
    Instance *c = (Instance *)comp;
    if (!c || s != fmi2LastSuccessfulTime) return fail(c, "fmi2GetRealStatus: unsupported status kind");
    *v = c->time;
    return fmi2OK;
}
fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *v) {
    (void)s;
    (void)v;
    return fail((Instance *)c, "fmi2GetIntegerStatus: unsupported status kind");
}
fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *v) {
    (void)s;
    (void)v;
    return fail((Instance *)c, "fmi2GetBooleanStatus: unsupported status kind");
}
fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *v) {
    (void)s;
    (void)v;
    return fail((Instance *)c, "fmi2GetStringStatus: unsupported status kind");
}
