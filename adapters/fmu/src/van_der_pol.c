/* The Van der Pol oscillator as an FMI 2.0 co-simulation FMU with no inputs (an autonomous
 * system) and an internal RK4 integrator.
 *
 * x0' = x1,  x1' = mu (1 - x0^2) x1 - x0
 *
 * Value references (must match van_der_pol.xml):
 *   0 x0, 1 x1 (outputs); 2 x0_start, 3 x1_start (initial state); 4 mu; 5 max_substep
 *   (largest RK4 substep, s). */

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "rk4.h"

#define GUID "{e94b8aed-b190-4606-9702-506848f7ecf3}"
#define NVARS 6
#define VR_X0 0
#define VR_X1 1
#define VR_X0_START 2
#define VR_X1_START 3
#define VR_MU 4
#define VR_MAX_SUBSTEP 5

typedef enum { ST_INSTANTIATED, ST_INIT, ST_STEP, ST_TERMINATED, ST_ERROR } Phase;

typedef struct {
    double v[NVARS]; /* every variable, indexed by value reference */
    double time;
    Phase phase;
    char *name;
    fmi2CallbackFunctions cb;
    int logging;
} Instance;

static const double DEFAULTS[NVARS] = {2.0, 0.0, 2.0, 0.0, 1.0, 1e-3};

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
    const double mu = p[0];
    (void)u; /* autonomous: no inputs */
    dx[0] = x[1];
    dx[1] = mu * (1.0 - x[0] * x[0]) * x[1] - x[0];
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
                       "van_der_pol supports co-simulation only");
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
    if (!isfinite(c->v[VR_MU])) return fail(c, "parameter mu must be finite");
    if (!(c->v[VR_MAX_SUBSTEP] > 0.0)) return fail(c, "parameter max_substep must be positive");
    if (!isfinite(c->v[VR_X0_START]) || !isfinite(c->v[VR_X1_START]))
        return fail(c, "initial state x0_start, x1_start must be finite");
    c->v[VR_X0] = c->v[VR_X0_START];
    c->v[VR_X1] = c->v[VR_X1_START];
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
        c->v[VR_X0] = c->v[VR_X0_START];
        c->v[VR_X1] = c->v[VR_X1_START];
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
        if (vr[i] == VR_X0 || vr[i] == VR_X1) return fail(c, "fmi2SetReal: outputs cannot be set");
        if (c->phase != ST_INSTANTIATED && c->phase != ST_INIT)
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
    double p[1], x[2];
    char msg[200];
    (void)noSetPrior;
    if (!c || c->phase != ST_STEP) return fail(c, "fmi2DoStep: the FMU is not initialized");
    if (!(h > 0.0)) return fail(c, "fmi2DoStep: communication step size must be positive");
    if (fabs(t - c->time) > 1e-9 * (1.0 + fabs(t))) {
        snprintf(msg, sizeof msg, "fmi2DoStep: communication point %.17g does not match the FMU time %.17g",
                 t, c->time);
        return fail(c, msg);
    }
    p[0] = c->v[VR_MU];
    x[0] = c->v[VR_X0];
    x[1] = c->v[VR_X1];
    if (rk4_advance(rhs, p, NULL, x, 2, h, c->v[VR_MAX_SUBSTEP]) < 0) {
        c->phase = ST_ERROR;
        return fail(c, "fmi2DoStep: the state became non-finite");
    }
    c->v[VR_X0] = x[0];
    c->v[VR_X1] = x[1];
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
