/* A test FMU (FMI 2.0 co-simulation) with a variable of every numeric FMI 2 type, for the FMU
 * adapter's type conversions: an integrator x' = gain * drive * s(mode) while `on` (s = +1 forward,
 * -1 reverse, 0 hold), exact per step (x += h * gain * drive * s), a step counter and echo outputs.
 *
 * Value references (must match typed_fmi2.xml), one table per type:
 *   Real:    0 x (output), 1 x0 (fixed parameter), 2 gain (tunable parameter), 3 offset (fixed parameter)
 *   Integer: 0 drive (input), 1 mode (Enumeration input), 2 steps (output), 3 mode_out (Enumeration output)
 *   Boolean: 0 on (input), 1 on_out (output)
 *   String:  0 label (fixed parameter). */

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

#define GUID "{9a7b6c5d-4e3f-4a1b-8c2d-0e1f2a3b4c5d}"

typedef enum { ST_INSTANTIATED, ST_INIT, ST_STEP, ST_TERMINATED } Phase;

typedef struct {
    double r[4];
    int i[4];
    int b[2];
    double time;
    Phase phase;
    fmi2CallbackFunctions cb;
    char *name;
} Instance;

static fmi2Status fail(Instance *c, const char *msg) {
    if (c && c->cb.logger) c->cb.logger(c->cb.componentEnvironment, c->name, fmi2Error, "logStatusError", msg);
    return fmi2Error;
}

static void set_defaults(Instance *c) {
    memset(c->r, 0, sizeof c->r);
    memset(c->i, 0, sizeof c->i);
    memset(c->b, 0, sizeof c->b);
    c->r[2] = 1.0;
    c->i[1] = 1;
    c->time = 0.0;
    c->phase = ST_INSTANTIATED;
}

/* Checks value references against `n` and, for setting, that the variable may be set now. */
static fmi2Status check(Instance *c, const char *fn, const fmi2ValueReference vr[], size_t nvr, unsigned n,
                        int setting, unsigned first_settable, unsigned last_settable) {
    size_t k;
    char msg[160];
    if (!c) return fmi2Error;
    for (k = 0; k < nvr; k++) {
        if (vr[k] >= n || (setting && (vr[k] < first_settable || vr[k] > last_settable))) {
            snprintf(msg, sizeof msg, "%s: value reference %u cannot be %s", fn, (unsigned)vr[k],
                     setting ? "set" : "read");
            return fail(c, msg);
        }
    }
    return fmi2OK;
}

/* ---- getters and setters ---- */
fmi2Status fmi2GetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t n, fmi2Real value[]) {
    Instance *c = (Instance *)comp;
    size_t k;
    if (check(c, "fmi2GetReal", vr, n, 4, 0, 0, 0) != fmi2OK) return fmi2Error;
    for (k = 0; k < n; k++) value[k] = vr[k] == 0 && c->phase == ST_INIT ? c->r[1] + c->r[3] : c->r[vr[k]];
    return fmi2OK;
}
fmi2Status fmi2SetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t n, const fmi2Real value[]) {
    Instance *c = (Instance *)comp;
    size_t k;
    if (check(c, "fmi2SetReal", vr, n, 4, 1, 1, 3) != fmi2OK) return fmi2Error;
    for (k = 0; k < n; k++) {
        if (vr[k] != 2 && c->phase != ST_INSTANTIATED && c->phase != ST_INIT)
            return fail(c, "fmi2SetReal: fixed parameters can only be set before initialization ends");
        c->r[vr[k]] = value[k];
    }
    return fmi2OK;
}
fmi2Status fmi2GetInteger(fmi2Component comp, const fmi2ValueReference vr[], size_t n, fmi2Integer value[]) {
    Instance *c = (Instance *)comp;
    size_t k;
    if (check(c, "fmi2GetInteger", vr, n, 4, 0, 0, 0) != fmi2OK) return fmi2Error;
    for (k = 0; k < n; k++) value[k] = vr[k] == 3 ? c->i[1] : c->i[vr[k]];
    return fmi2OK;
}
fmi2Status fmi2SetInteger(fmi2Component comp, const fmi2ValueReference vr[], size_t n, const fmi2Integer value[]) {
    Instance *c = (Instance *)comp;
    size_t k;
    if (check(c, "fmi2SetInteger", vr, n, 4, 1, 0, 1) != fmi2OK) return fmi2Error;
    for (k = 0; k < n; k++) c->i[vr[k]] = value[k];
    return fmi2OK;
}
fmi2Status fmi2GetBoolean(fmi2Component comp, const fmi2ValueReference vr[], size_t n, fmi2Boolean value[]) {
    Instance *c = (Instance *)comp;
    size_t k;
    if (check(c, "fmi2GetBoolean", vr, n, 2, 0, 0, 0) != fmi2OK) return fmi2Error;
    for (k = 0; k < n; k++) value[k] = c->b[0];
    return fmi2OK;
}
fmi2Status fmi2SetBoolean(fmi2Component comp, const fmi2ValueReference vr[], size_t n, const fmi2Boolean value[]) {
    Instance *c = (Instance *)comp;
    size_t k;
    if (check(c, "fmi2SetBoolean", vr, n, 2, 1, 0, 0) != fmi2OK) return fmi2Error;
    for (k = 0; k < n; k++) c->b[0] = value[k] != fmi2False;
    return fmi2OK;
}
fmi2Status fmi2GetString(fmi2Component comp, const fmi2ValueReference vr[], size_t n, fmi2String value[]) {
    Instance *c = (Instance *)comp;
    size_t k;
    if (check(c, "fmi2GetString", vr, n, 1, 0, 0, 0) != fmi2OK) return fmi2Error;
    for (k = 0; k < n; k++) value[k] = "typed";
    return fmi2OK;
}
fmi2Status fmi2SetString(fmi2Component comp, const fmi2ValueReference vr[], size_t n, const fmi2String value[]) {
    (void)value;
    return check((Instance *)comp, "fmi2SetString", vr, n, 1, 1, 0, 0);
}

/* ---- common functions ---- */
const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cats[]) {
    (void)on;
    (void)n;
    (void)cats;
    return c ? fmi2OK : fmi2Error;
}

fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String res,
                              const fmi2CallbackFunctions *cb, fmi2Boolean visible, fmi2Boolean logging) {
    Instance *c;
    (void)res;
    (void)visible;
    (void)logging;
    if (!cb || !name) return NULL;
    if (type != fmi2CoSimulation || !guid || strcmp(guid, GUID) != 0) {
        if (cb->logger)
            cb->logger(cb->componentEnvironment, name, fmi2Error, "logStatusError",
                       "typed_fmi2: co-simulation only, and the GUID must match");
        return NULL;
    }
    c = (Instance *)calloc(1, sizeof(Instance));
    if (!c) return NULL;
    c->name = strdup(name);
    c->cb = *cb;
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
    c->r[0] = c->r[1] + c->r[3];
    c->i[2] = 0;
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
    return fmi2OK;
}

/* ---- functions of capabilities the FMU does not declare ---- */
#define UNUSED_ARGS_BEGIN _Pragma("GCC diagnostic push") _Pragma("GCC diagnostic ignored \"-Wunused-parameter\"")
#define UNUSED_ARGS_END _Pragma("GCC diagnostic pop")
#define UNSUPPORTED(fn, ...) \
    fmi2Status fn(fmi2Component c_, __VA_ARGS__) { return fail((Instance *)c_, #fn " is not supported"); }
UNUSED_ARGS_BEGIN
UNSUPPORTED(fmi2GetFMUstate, fmi2FMUstate *s)
UNSUPPORTED(fmi2SetFMUstate, fmi2FMUstate s)
UNSUPPORTED(fmi2FreeFMUstate, fmi2FMUstate *s)
UNSUPPORTED(fmi2SerializedFMUstateSize, fmi2FMUstate s, size_t *n)
UNSUPPORTED(fmi2SerializeFMUstate, fmi2FMUstate s, fmi2Byte b[], size_t n)
UNSUPPORTED(fmi2DeSerializeFMUstate, const fmi2Byte b[], size_t n, fmi2FMUstate *s)
UNSUPPORTED(fmi2GetDirectionalDerivative, const fmi2ValueReference u[], size_t nu, const fmi2ValueReference z[],
            size_t nz, const fmi2Real dv[], fmi2Real dz[])
UNSUPPORTED(fmi2SetRealInputDerivatives, const fmi2ValueReference vr[], size_t n, const fmi2Integer order[],
            const fmi2Real value[])
UNSUPPORTED(fmi2GetRealOutputDerivatives, const fmi2ValueReference vr[], size_t n, const fmi2Integer order[],
            fmi2Real value[])
UNSUPPORTED(fmi2GetStatus, const fmi2StatusKind s, fmi2Status *v)
UNSUPPORTED(fmi2GetIntegerStatus, const fmi2StatusKind s, fmi2Integer *v)
UNSUPPORTED(fmi2GetBooleanStatus, const fmi2StatusKind s, fmi2Boolean *v)
UNSUPPORTED(fmi2GetStringStatus, const fmi2StatusKind s, fmi2String *v)
UNUSED_ARGS_END

fmi2Status fmi2CancelStep(fmi2Component c) { return fail((Instance *)c, "fmi2CancelStep: steps are synchronous"); }

fmi2Status fmi2GetRealStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Real *v) {
    Instance *c = (Instance *)comp;
    if (!c || s != fmi2LastSuccessfulTime) return fail(c, "fmi2GetRealStatus: unsupported status kind");
    *v = c->time;
    return fmi2OK;
}

/* ---- co-simulation ---- */
fmi2Status fmi2DoStep(fmi2Component comp, fmi2Real t, fmi2Real h, fmi2Boolean noSetPrior) {
    Instance *c = (Instance *)comp;
    (void)noSetPrior;
    if (!c || c->phase != ST_STEP) return fail(c, "fmi2DoStep: the FMU is not initialized");
    if (!(h > 0.0)) return fail(c, "fmi2DoStep: communication step size must be positive");
    if (c->i[1] < 1 || c->i[1] > 3) return fail(c, "fmi2DoStep: mode must be 1, 2 or 3");
    if (c->b[0]) c->r[0] += h * c->r[2] * (double)c->i[0] * (c->i[1] == 1 ? 1.0 : c->i[1] == 2 ? -1.0 : 0.0);
    c->i[2] += 1;
    c->time = t + h;
    return fmi2OK;
}
