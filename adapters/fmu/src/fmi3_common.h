/* What the project's FMI 3.0 co-simulation FMUs share: the instance and its phases, error logging,
 * the lifecycle functions, and the functions of interfaces and capabilities they do not declare.
 *
 * Include once, in the model's only source file, after defining:
 *   FMU_NAME       the model's name (a string literal, for messages);
 *   TOKEN          its instantiation token (a string literal, as in its modelDescription.xml);
 *   Model          a struct type with the model's own variables (Instance.m);
 *   MODEL_TIME(c)  the model's time variable of instance c (an lvalue of type double);
 * and then define the two hooks declared below (model_reset, model_initialize). The model file keeps
 * its getters and setters, fmi3Enter/ExitConfigurationMode and fmi3DoStep (do_step_checks helps). */
#ifndef KOOPBRIDGE_FMI3_COMMON_H
#define KOOPBRIDGE_FMI3_COMMON_H

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi3Functions.h"

typedef enum { ST_INSTANTIATED, ST_INIT, ST_STEP, ST_TERMINATED, ST_ERROR } Phase;

/* One instance of the FMU. */
typedef struct {
    Model m; /* the model's own variables */
    Phase phase;
    fmi3InstanceEnvironment env;
    fmi3LogMessageCallback log;
} Instance;

/* Hook: sets the model's variables, the time included, to their start values (at instantiation and
 * fmi3Reset). */
static void model_reset(Instance *c);
/* Hook: checks the parameters and sets up the initial state when initialization mode ends; an error
 * (reported with fail) keeps the FMU in initialization mode. */
static fmi3Status model_initialize(Instance *c);

/* Logs `msg` as an error through the environment's logger (when there is one); returns fmi3Error. */
static fmi3Status fail(Instance *c, const char *msg) {
    if (c && c->log) c->log(c->env, fmi3Error, "logStatusError", msg);
    return fmi3Error;
}

/* Back to the instantiated phase with every variable at its start value. */
static void reset_instance(Instance *c) {
    model_reset(c);
    c->phase = ST_INSTANTIATED;
}

/* The checks every fmi3DoStep starts with: clears the flags it returns (no event, no termination, no
 * early return), then checks that the FMU is initialized. */
static fmi3Status do_step_checks(Instance *c, fmi3Boolean *eventNeeded, fmi3Boolean *terminate,
                                 fmi3Boolean *earlyReturn) {
    if (eventNeeded) *eventNeeded = fmi3False;
    if (terminate) *terminate = fmi3False;
    if (earlyReturn) *earlyReturn = fmi3False;
    if (!c || c->phase != ST_STEP) return fail(c, "fmi3DoStep: the FMU is not initialized");
    return fmi3OK;
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
    if (log) log(env, fmi3Error, "logStatusError", FMU_NAME " supports co-simulation only");
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
    if (log) log(env, fmi3Error, "logStatusError", FMU_NAME " supports co-simulation only");
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
    c->env = env;
    c->log = log;
    reset_instance(c);
    return c;
}

void fmi3FreeInstance(fmi3Instance inst) { free(inst); }

fmi3Status fmi3EnterInitializationMode(fmi3Instance inst, fmi3Boolean tolDef, fmi3Float64 tol, fmi3Float64 start,
                                       fmi3Boolean stopDef, fmi3Float64 stop) {
    Instance *c = (Instance *)inst;
    (void)tolDef;
    (void)tol;
    (void)stopDef;
    (void)stop;
    if (!c || c->phase != ST_INSTANTIATED) return fail(c, "fmi3EnterInitializationMode: wrong state");
    MODEL_TIME(c) = start;
    c->phase = ST_INIT;
    return fmi3OK;
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance inst) {
    Instance *c = (Instance *)inst;
    if (!c || c->phase != ST_INIT) return fail(c, "fmi3ExitInitializationMode: wrong state");
    if (model_initialize(c) != fmi3OK) return fmi3Error;
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
    reset_instance(c);
    return fmi3OK;
}

/* Getters and setters of a type the model has no variable of: an error unless called for none. */
#define FMI3_NO_VARS(fn, T)                                                                           \
    fmi3Status fn(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, T values[], size_t nv) { \
        (void)vr;                                                                                     \
        (void)values;                                                                                 \
        (void)nv;                                                                                     \
        return nvr == 0 ? fmi3OK : fail((Instance *)c, #fn ": the model has no such variables");      \
    }

/* Functions of capabilities the FMU does not declare: they report an error and change nothing. */
#define FMI3_UNSUPPORTED(fn, ...)                                            \
    fmi3Status fn(fmi3Instance inst_, __VA_ARGS__) {                         \
        return fail((Instance *)inst_, #fn " is not supported by this FMU"); \
    }
#define UNUSED_ARGS_BEGIN _Pragma("GCC diagnostic push") _Pragma("GCC diagnostic ignored \"-Wunused-parameter\"")
#define UNUSED_ARGS_END _Pragma("GCC diagnostic pop")

UNUSED_ARGS_BEGIN
FMI3_UNSUPPORTED(fmi3GetClock, const fmi3ValueReference vr[], size_t nvr, fmi3Clock v[])
FMI3_UNSUPPORTED(fmi3SetClock, const fmi3ValueReference vr[], size_t nvr, const fmi3Clock v[])
FMI3_UNSUPPORTED(fmi3GetNumberOfVariableDependencies, fmi3ValueReference vr, size_t *n)
FMI3_UNSUPPORTED(fmi3GetVariableDependencies, fmi3ValueReference d, size_t ed[], fmi3ValueReference ind[],
                 size_t ei[], fmi3DependencyKind k[], size_t n)
FMI3_UNSUPPORTED(fmi3GetFMUState, fmi3FMUState *s)
FMI3_UNSUPPORTED(fmi3SetFMUState, fmi3FMUState s)
FMI3_UNSUPPORTED(fmi3FreeFMUState, fmi3FMUState *s)
FMI3_UNSUPPORTED(fmi3SerializedFMUStateSize, fmi3FMUState s, size_t *n)
FMI3_UNSUPPORTED(fmi3SerializeFMUState, fmi3FMUState s, fmi3Byte b[], size_t n)
FMI3_UNSUPPORTED(fmi3DeserializeFMUState, const fmi3Byte b[], size_t n, fmi3FMUState *s)
FMI3_UNSUPPORTED(fmi3GetDirectionalDerivative, const fmi3ValueReference u[], size_t nu, const fmi3ValueReference k[],
                 size_t nk, const fmi3Float64 seed[], size_t ns, fmi3Float64 sens[], size_t nsens)
FMI3_UNSUPPORTED(fmi3GetAdjointDerivative, const fmi3ValueReference u[], size_t nu, const fmi3ValueReference k[],
                 size_t nk, const fmi3Float64 seed[], size_t ns, fmi3Float64 sens[], size_t nsens)
FMI3_UNSUPPORTED(fmi3GetIntervalDecimal, const fmi3ValueReference vr[], size_t n, fmi3Float64 iv[],
                 fmi3IntervalQualifier q[])
FMI3_UNSUPPORTED(fmi3GetIntervalFraction, const fmi3ValueReference vr[], size_t n, fmi3UInt64 c[], fmi3UInt64 r[],
                 fmi3IntervalQualifier q[])
FMI3_UNSUPPORTED(fmi3GetShiftDecimal, const fmi3ValueReference vr[], size_t n, fmi3Float64 s[])
FMI3_UNSUPPORTED(fmi3GetShiftFraction, const fmi3ValueReference vr[], size_t n, fmi3UInt64 c[], fmi3UInt64 r[])
FMI3_UNSUPPORTED(fmi3SetIntervalDecimal, const fmi3ValueReference vr[], size_t n, const fmi3Float64 iv[])
FMI3_UNSUPPORTED(fmi3SetIntervalFraction, const fmi3ValueReference vr[], size_t n, const fmi3UInt64 c[],
                 const fmi3UInt64 r[])
FMI3_UNSUPPORTED(fmi3SetShiftDecimal, const fmi3ValueReference vr[], size_t n, const fmi3Float64 s[])
FMI3_UNSUPPORTED(fmi3SetShiftFraction, const fmi3ValueReference vr[], size_t n, const fmi3UInt64 c[],
                 const fmi3UInt64 r[])
FMI3_UNSUPPORTED(fmi3UpdateDiscreteStates, fmi3Boolean *a, fmi3Boolean *b, fmi3Boolean *d, fmi3Boolean *e,
                 fmi3Boolean *f, fmi3Float64 *t)
FMI3_UNSUPPORTED(fmi3CompletedIntegratorStep, fmi3Boolean no, fmi3Boolean *e, fmi3Boolean *t)
FMI3_UNSUPPORTED(fmi3SetTime, fmi3Float64 t)
FMI3_UNSUPPORTED(fmi3SetContinuousStates, const fmi3Float64 x[], size_t n)
FMI3_UNSUPPORTED(fmi3GetContinuousStateDerivatives, fmi3Float64 dx[], size_t n)
FMI3_UNSUPPORTED(fmi3GetEventIndicators, fmi3Float64 e[], size_t n)
FMI3_UNSUPPORTED(fmi3GetContinuousStates, fmi3Float64 x[], size_t n)
FMI3_UNSUPPORTED(fmi3GetNominalsOfContinuousStates, fmi3Float64 x[], size_t n)
FMI3_UNSUPPORTED(fmi3GetNumberOfEventIndicators, size_t *n)
FMI3_UNSUPPORTED(fmi3GetNumberOfContinuousStates, size_t *n)
FMI3_UNSUPPORTED(fmi3GetOutputDerivatives, const fmi3ValueReference vr[], size_t nvr, const fmi3Int32 o[],
                 fmi3Float64 v[], size_t nv)
FMI3_UNSUPPORTED(fmi3ActivateModelPartition, fmi3ValueReference clock, fmi3Float64 t)
UNUSED_ARGS_END

fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance c) { return fail((Instance *)c, "no discrete states"); }
fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance c) { return fail((Instance *)c, "co-simulation only"); }

/* ---- co-simulation ---- */
fmi3Status fmi3EnterStepMode(fmi3Instance c) {
    return fail((Instance *)c, "fmi3EnterStepMode: event mode is not used by this FMU");
}

#endif
