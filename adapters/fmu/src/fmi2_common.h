/* What the project's FMI 2.0 co-simulation FMUs share: the instance and its phases, error logging,
 * the lifecycle functions, and the functions of capabilities they do not declare.
 *
 * Include once, in the model's only source file, after defining:
 *   FMU_NAME  the model's name (a string literal, for messages);
 *   GUID      its guid (a string literal, as in its modelDescription.xml);
 *   Model     a struct type with the model's own variables (Instance.m);
 * and then define the two hooks declared below (model_reset, model_initialize). The model file keeps
 * its getters and setters and fmi2DoStep (do_step_checks and check_communication_point help). */
#ifndef KOOPBRIDGE_FMI2_COMMON_H
#define KOOPBRIDGE_FMI2_COMMON_H

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

typedef enum { ST_INSTANTIATED, ST_INIT, ST_STEP, ST_TERMINATED, ST_ERROR } Phase;

/* One instance of the FMU. */
typedef struct {
    Model m; /* the model's own variables */
    double time;
    Phase phase;
    char *name;
    fmi2CallbackFunctions cb;
} Instance;

/* Hook: sets the model's variables to their start values (at instantiation and fmi2Reset). */
static void model_reset(Instance *c);
/* Hook: checks the parameters and sets up the initial state when initialization mode ends; an error
 * (reported with fail) keeps the FMU in initialization mode. */
static fmi2Status model_initialize(Instance *c);

/* Logs `msg` as an error through the environment's logger (when there is one); returns fmi2Error. */
static fmi2Status fail(Instance *c, const char *msg) {
    if (c && c->cb.logger) c->cb.logger(c->cb.componentEnvironment, c->name, fmi2Error, "logStatusError", "%s", msg);
    return fmi2Error;
}

/* Back to the instantiated phase at time 0 with every variable at its start value. */
static void reset_instance(Instance *c) {
    model_reset(c);
    c->time = 0.0;
    c->phase = ST_INSTANTIATED;
}

/* The checks every fmi2DoStep starts with: the FMU is initialized and the step size is positive. */
static fmi2Status do_step_checks(Instance *c, fmi2Real h) {
    if (!c || c->phase != ST_STEP) return fail(c, "fmi2DoStep: the FMU is not initialized");
    if (!(h > 0.0)) return fail(c, "fmi2DoStep: communication step size must be positive");
    return fmi2OK;
}

/* Checks that the communication point `t` of fmi2DoStep is the FMU's time (to 1e-9 relative). */
static inline fmi2Status check_communication_point(Instance *c, fmi2Real t) {
    char msg[200];
    if (fabs(t - c->time) > 1e-9 * (1.0 + fabs(t))) {
        snprintf(msg, sizeof msg, "fmi2DoStep: communication point %.17g does not match the FMU time %.17g", t,
                 c->time);
        return fail(c, msg);
    }
    return fmi2OK;
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
    if (type != fmi2CoSimulation) {
        if (cb->logger)
            cb->logger(cb->componentEnvironment, name, fmi2Error, "logStatusError",
                       FMU_NAME " supports co-simulation only");
        return NULL;
    }
    if (!guid || strcmp(guid, GUID) != 0) {
        if (cb->logger)
            cb->logger(cb->componentEnvironment, name, fmi2Error, "logStatusError", "GUID mismatch: expected %s",
                       GUID);
        return NULL;
    }
    c = (Instance *)calloc(1, sizeof(Instance));
    if (!c) return NULL;
    c->name = strdup(name);
    c->cb = *cb;
    reset_instance(c);
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
    if (model_initialize(c) != fmi2OK) return fmi2Error;
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
    reset_instance(c);
    return fmi2OK;
}

/* Getters and setters of a type the model has no variable of: an error unless called for none. */
#define FMI2_NO_VARS(fn, T)                                                                       \
    fmi2Status fn(fmi2Component comp, const fmi2ValueReference vr[], size_t n, T value[]) {       \
        (void)vr;                                                                                 \
        (void)value;                                                                              \
        return n == 0 ? fmi2OK : fail((Instance *)comp, #fn ": the model has no such variables"); \
    }
/* The Integer, Boolean and String getters and setters of a model with Real variables only. */
#define FMI2_REAL_VARIABLES_ONLY                    \
    FMI2_NO_VARS(fmi2GetInteger, fmi2Integer)       \
    FMI2_NO_VARS(fmi2GetBoolean, fmi2Boolean)       \
    FMI2_NO_VARS(fmi2GetString, fmi2String)         \
    FMI2_NO_VARS(fmi2SetInteger, const fmi2Integer) \
    FMI2_NO_VARS(fmi2SetBoolean, const fmi2Boolean) \
    FMI2_NO_VARS(fmi2SetString, const fmi2String)

/* ---- functions of capabilities the FMUs do not declare: they report an error and change nothing ---- */
#define UNUSED_ARGS_BEGIN _Pragma("GCC diagnostic push") _Pragma("GCC diagnostic ignored \"-Wunused-parameter\"")
#define UNUSED_ARGS_END _Pragma("GCC diagnostic pop")
#define FMI2_UNSUPPORTED(fn, msg, ...) \
    fmi2Status fn(fmi2Component c_, __VA_ARGS__) { return fail((Instance *)c_, msg); }
UNUSED_ARGS_BEGIN
FMI2_UNSUPPORTED(fmi2GetFMUstate, "fmi2GetFMUstate is not supported", fmi2FMUstate *s)
FMI2_UNSUPPORTED(fmi2SetFMUstate, "fmi2SetFMUstate is not supported", fmi2FMUstate s)
FMI2_UNSUPPORTED(fmi2FreeFMUstate, "fmi2FreeFMUstate is not supported", fmi2FMUstate *s)
FMI2_UNSUPPORTED(fmi2SerializedFMUstateSize, "FMU state serialization is not supported", fmi2FMUstate s, size_t *n)
FMI2_UNSUPPORTED(fmi2SerializeFMUstate, "FMU state serialization is not supported", fmi2FMUstate s, fmi2Byte b[],
                 size_t n)
FMI2_UNSUPPORTED(fmi2DeSerializeFMUstate, "FMU state serialization is not supported", const fmi2Byte b[], size_t n,
                 fmi2FMUstate *s)
FMI2_UNSUPPORTED(fmi2GetDirectionalDerivative, "directional derivatives are not provided", const fmi2ValueReference u[],
                 size_t nu, const fmi2ValueReference z[], size_t nz, const fmi2Real dv[], fmi2Real dz[])
FMI2_UNSUPPORTED(fmi2SetRealInputDerivatives, "input derivatives are not supported", const fmi2ValueReference vr[],
                 size_t n, const fmi2Integer order[], const fmi2Real value[])
FMI2_UNSUPPORTED(fmi2GetRealOutputDerivatives, "output derivatives are not supported", const fmi2ValueReference vr[],
                 size_t n, const fmi2Integer order[], fmi2Real value[])
FMI2_UNSUPPORTED(fmi2GetStatus, "fmi2GetStatus: steps are synchronous", const fmi2StatusKind s, fmi2Status *v)
FMI2_UNSUPPORTED(fmi2GetIntegerStatus, "fmi2GetIntegerStatus: unsupported status kind", const fmi2StatusKind s,
                 fmi2Integer *v)
FMI2_UNSUPPORTED(fmi2GetBooleanStatus, "fmi2GetBooleanStatus: unsupported status kind", const fmi2StatusKind s,
                 fmi2Boolean *v)
FMI2_UNSUPPORTED(fmi2GetStringStatus, "fmi2GetStringStatus: unsupported status kind", const fmi2StatusKind s,
                 fmi2String *v)
UNUSED_ARGS_END

fmi2Status fmi2CancelStep(fmi2Component c) { return fail((Instance *)c, "fmi2CancelStep: steps are synchronous"); }

fmi2Status fmi2GetRealStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Real *v) {
    Instance *c = (Instance *)comp;
    if (!c || s != fmi2LastSuccessfulTime) return fail(c, "fmi2GetRealStatus: unsupported status kind");
    *v = c->time;
    return fmi2OK;
}

#endif
