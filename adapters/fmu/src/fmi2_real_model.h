/* The getters and setters of an FMI 2.0 model whose variables are all Reals, kept in Model.v by
 * value reference: its states (also its outputs), then its inputs, then its parameters, the first
 * N_STATES of them the initial state.
 *
 * Include once, after fmi2_common.h, having defined in the model file:
 *   Model          with a member `double v[NVARS]`;
 *   N_STATES       the number of states: value references 0 .. N_STATES - 1;
 *   VR_STATE_START the value reference of the first parameter, the start of the state (the inputs
 *                  lie between N_STATES and VR_STATE_START). */
#ifndef KOOPBRIDGE_FMI2_REAL_MODEL_H
#define KOOPBRIDGE_FMI2_REAL_MODEL_H

/* Sets the states to the initial state parameters. */
static void load_initial_state(Instance *c) {
    int i;
    for (i = 0; i < N_STATES; i++) c->m.v[i] = c->m.v[VR_STATE_START + i];
}

fmi2Status fmi2GetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t n, fmi2Real value[]) {
    Instance *c = (Instance *)comp;
    size_t i;
    if (!c) return fmi2Error;
    if (c->phase == ST_INIT) load_initial_state(c); /* outputs are calculated from the initial state */
    for (i = 0; i < n; i++) {
        if (vr[i] >= NVARS) return fail(c, "fmi2GetReal: unknown value reference");
        value[i] = c->m.v[vr[i]];
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t n, const fmi2Real value[]) {
    Instance *c = (Instance *)comp;
    size_t i;
    if (!c) return fmi2Error;
    for (i = 0; i < n; i++) {
        if (vr[i] >= NVARS) return fail(c, "fmi2SetReal: unknown value reference");
        if (vr[i] < N_STATES) return fail(c, "fmi2SetReal: outputs cannot be set");
        if (vr[i] >= VR_STATE_START && c->phase != ST_INSTANTIATED && c->phase != ST_INIT)
            return fail(c, "fmi2SetReal: parameters can only be set before initialization ends");
        c->m.v[vr[i]] = value[i];
    }
    return fmi2OK;
}

FMI2_REAL_VARIABLES_ONLY

#endif
