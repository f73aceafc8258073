/* A test FMU (FMI 2.0 co-simulation) with a variable of every numeric FMI 2 type, for the FMU
 * adapter's type conversions: an integrator x' = gain * drive * s(mode) while `on` (s = +1 forward,
 * -1 reverse, 0 hold), exact per step (x += h * gain * drive * s), a step counter and echo outputs.
 *
 * Value references (must match typed_fmi2.xml), one table per type:
 *   Real:    0 x (output), 1 x0 (fixed parameter), 2 gain (tunable parameter), 3 offset (fixed parameter)
 *   Integer: 0 drive (input), 1 mode (Enumeration input), 2 steps (output), 3 mode_out (Enumeration output)
 *   Boolean: 0 on (input), 1 on_out (output)
 *   String:  0 label (fixed parameter). */

#define FMU_NAME "typed_fmi2"
#define GUID "{9a7b6c5d-4e3f-4a1b-8c2d-0e1f2a3b4c5d}"

typedef struct {
    double r[4];
    int i[4];
    int b[2];
} Model;

#include "fmi2_common.h"

static void model_reset(Instance *c) {
    memset(&c->m, 0, sizeof c->m);
    c->m.r[2] = 1.0;
    c->m.i[1] = 1;
}

static fmi2Status model_initialize(Instance *c) {
    c->m.r[0] = c->m.r[1] + c->m.r[3];
    c->m.i[2] = 0;
    return fmi2OK;
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
    for (k = 0; k < n; k++) value[k] = vr[k] == 0 && c->phase == ST_INIT ? c->m.r[1] + c->m.r[3] : c->m.r[vr[k]];
    return fmi2OK;
}
fmi2Status fmi2SetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t n, const fmi2Real value[]) {
    Instance *c = (Instance *)comp;
    size_t k;
    if (check(c, "fmi2SetReal", vr, n, 4, 1, 1, 3) != fmi2OK) return fmi2Error;
    for (k = 0; k < n; k++) {
        if (vr[k] != 2 && c->phase != ST_INSTANTIATED && c->phase != ST_INIT)
            return fail(c, "fmi2SetReal: fixed parameters can only be set before initialization ends");
        c->m.r[vr[k]] = value[k];
    }
    return fmi2OK;
}
fmi2Status fmi2GetInteger(fmi2Component comp, const fmi2ValueReference vr[], size_t n, fmi2Integer value[]) {
    Instance *c = (Instance *)comp;
    size_t k;
    if (check(c, "fmi2GetInteger", vr, n, 4, 0, 0, 0) != fmi2OK) return fmi2Error;
    for (k = 0; k < n; k++) value[k] = vr[k] == 3 ? c->m.i[1] : c->m.i[vr[k]];
    return fmi2OK;
}
fmi2Status fmi2SetInteger(fmi2Component comp, const fmi2ValueReference vr[], size_t n, const fmi2Integer value[]) {
    Instance *c = (Instance *)comp;
    size_t k;
    if (check(c, "fmi2SetInteger", vr, n, 4, 1, 0, 1) != fmi2OK) return fmi2Error;
    for (k = 0; k < n; k++) c->m.i[vr[k]] = value[k];
    return fmi2OK;
}
fmi2Status fmi2GetBoolean(fmi2Component comp, const fmi2ValueReference vr[], size_t n, fmi2Boolean value[]) {
    Instance *c = (Instance *)comp;
    size_t k;
    if (check(c, "fmi2GetBoolean", vr, n, 2, 0, 0, 0) != fmi2OK) return fmi2Error;
    for (k = 0; k < n; k++) value[k] = c->m.b[0];
    return fmi2OK;
}
fmi2Status fmi2SetBoolean(fmi2Component comp, const fmi2ValueReference vr[], size_t n, const fmi2Boolean value[]) {
    Instance *c = (Instance *)comp;
    size_t k;
    if (check(c, "fmi2SetBoolean", vr, n, 2, 1, 0, 0) != fmi2OK) return fmi2Error;
    for (k = 0; k < n; k++) c->m.b[0] = value[k] != fmi2False;
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

/* ---- co-simulation ---- */
fmi2Status fmi2DoStep(fmi2Component comp, fmi2Real t, fmi2Real h, fmi2Boolean noSetPrior) {
    Instance *c = (Instance *)comp;
    (void)noSetPrior;
    if (do_step_checks(c, h) != fmi2OK) return fmi2Error;
    if (c->m.i[1] < 1 || c->m.i[1] > 3) return fail(c, "fmi2DoStep: mode must be 1, 2 or 3");
    if (c->m.b[0])
        c->m.r[0] += h * c->m.r[2] * (double)c->m.i[0] * (c->m.i[1] == 1 ? 1.0 : c->m.i[1] == 2 ? -1.0 : 0.0);
    c->m.i[2] += 1;
    c->time = t + h;
    return fmi2OK;
}
