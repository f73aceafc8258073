/* A test FMU (FMI 3.0 co-simulation) with a variable of every numeric FMI 3 type, for the FMU
 * adapter's type conversions: an integrator x' = gain * drive * s(mode) while `on` (s = +1 forward,
 * -1 reverse, 0 hold), exact per step (x += h * gain * drive * s), echo outputs of every integer
 * input, a step counter that wraps at 256, and arrays y[n] (y[i] = (i + 1) x, n a structural
 * parameter, at most 8) and M[2,2] (M[i,j] = x + 10 i + j).
 *
 * Value references (must match typed_fmi3.xml):
 *   0 time; 1 x (Float64 out); 2 x0 (Float64 param); 3 drive (Int32 in); 4 on (Boolean in);
 *   5 mode (Enumeration in); 6 gain (Float32 in); 7 i8, 8 u8, 9 i16, 10 u16, 11 u32, 12 i64,
 *   13 u64 (inputs of those types); 14 steps (UInt8 out); 15 xf (Float32 out, = x);
 *   16 .. 23 i8_out, u8_out, i16_out, u16_out, i32_out (= drive), u32_out, i64_out, u64_out;
 *   24 on_out (Boolean); 25 mode_out (Enumeration); 26 n (UInt64 structural parameter);
 *   27 y (Float64[n] out); 28 M (Float64[2,2] out); 29 label (String param); 30 blob (Binary param);
 *   31 w (Float64[2] in); 32 wsum (Float64 out, = w[0] + 2 w[1]). */

#include <stdint.h>

#define FMU_NAME "typed_fmi3"
#define TOKEN "{5d0c2b7e-8a41-4f3c-9e6d-1b2a3c4d5e6f}"
#define NVARS 33
#define NMAX 8

enum { F64, F32, I8, U8, I16, U16, I32, U32, I64, U64, BOOL, ENUM, STR, BIN };
/* The type of each value reference. */
static const int TYPE[NVARS] = {F64, F64, F64, I32, BOOL, ENUM, F32, I8, U8, I16, U16, U32, I64, U64, U8, F32,
                                I8, U8, I16, U16, I32, U32, I64, U64, BOOL, ENUM, U64, F64, F64, STR, BIN, F64, F64};
enum { VR_TIME, VR_X, VR_X0, VR_DRIVE, VR_ON, VR_MODE, VR_GAIN, VR_I8, VR_U64 = 13, VR_STEPS, VR_XF, VR_ECHO,
       VR_ON_OUT = 24, VR_MODE_OUT, VR_N, VR_Y, VR_M, VR_LABEL, VR_BLOB, VR_W, VR_WSUM };

typedef union {
    double f;
    int64_t i;
    uint64_t u;
} Value;

typedef struct {
    Value v[NVARS];
    double w[2];
} Model;
#define MODEL_TIME(c) ((c)->m.v[VR_TIME].f)

#include "fmi3_common.h"

static void model_reset(Instance *c) {
    memset(&c->m, 0, sizeof c->m);
    c->m.v[VR_MODE].i = 1;
    c->m.v[VR_GAIN].f = 1.0;
    c->m.v[VR_N].u = 3;
}

static fmi3Status model_initialize(Instance *c) {
    c->m.v[VR_X].f = c->m.v[VR_X0].f;
    c->m.v[VR_STEPS].i = 0;
    return fmi3OK;
}

/* The value of scalar `vr` (outputs computed from the state and the inputs). */
static Value value_of(const Instance *c, fmi3ValueReference vr) {
    Value r;
    if (vr == VR_X && c->phase == ST_INIT) {
        r.f = c->m.v[VR_X0].f;
    } else if (vr == VR_XF) {
        r.f = (float)(c->phase == ST_INIT ? c->m.v[VR_X0].f : c->m.v[VR_X].f);
    } else if (vr >= VR_ECHO && vr < VR_ECHO + 8) {
        static const int SRC[8] = {7, 8, 9, 10, 3, 11, 12, 13};
        r = c->m.v[SRC[vr - VR_ECHO]];
    } else if (vr == VR_WSUM) {
        r.f = c->m.w[0] + 2.0 * c->m.w[1];
    } else if (vr == VR_ON_OUT) {
        r = c->m.v[VR_ON];
    } else if (vr == VR_MODE_OUT) {
        r = c->m.v[VR_MODE];
    } else {
        r = c->m.v[vr];
    }
    return r;
}

/* The number of values of `vr` (arrays: their size). */
static size_t size_of(const Instance *c, fmi3ValueReference vr) {
    if (vr == VR_Y) return (size_t)c->m.v[VR_N].u;
    if (vr == VR_M) return 4;
    if (vr == VR_W) return 2;
    return 1;
}

/* Reads the values of `vr[]` (of the types `t1`/`t2`) as doubles, int64 or uint64 into `out`. */
static fmi3Status get_values(Instance *c, const char *fn, const fmi3ValueReference vr[], size_t nvr, int t1, int t2,
                             Value out[], size_t nv) {
    size_t i, j, k = 0;
    char msg[160];
    if (!c) return fmi3Error;
    for (i = 0; i < nvr; i++) {
        if (vr[i] >= NVARS || (TYPE[vr[i]] != t1 && TYPE[vr[i]] != t2)) {
            snprintf(msg, sizeof msg, "%s: value reference %u is not of this type", fn, (unsigned)vr[i]);
            return fail(c, msg);
        }
        if (k + size_of(c, vr[i]) > nv) return fail(c, "nValues is too small");
        if (vr[i] == VR_W) {
            out[k++].f = c->m.w[0];
            out[k++].f = c->m.w[1];
        } else if (vr[i] == VR_Y || vr[i] == VR_M) {
            const double x = c->phase == ST_INIT ? c->m.v[VR_X0].f : c->m.v[VR_X].f;
            for (j = 0; j < size_of(c, vr[i]); j++)
                out[k++].f = vr[i] == VR_Y ? (double)(j + 1) * x : x + 10.0 * (double)(j / 2) + (double)(j % 2);
        } else {
            out[k++] = value_of(c, vr[i]);
        }
    }
    if (k != nv) return fail(c, "nValues does not match the sizes of the variables");
    return fmi3OK;
}

/* Checks that `vr[]` are of the type `t1`/`t2` and may be set now; returns 0 or fails. */
static fmi3Status check_set(Instance *c, const char *fn, const fmi3ValueReference vr[], size_t nvr, int t1, int t2,
                            size_t nv) {
    size_t i, total = 0;
    char msg[160];
    if (!c) return fmi3Error;
    for (i = 0; i < nvr; i++) total += vr[i] < NVARS ? size_of(c, vr[i]) : 1;
    if (nv != total) return fail(c, "set: nValues does not match the sizes of the variables");
    for (i = 0; i < nvr; i++) {
        const fmi3ValueReference r = vr[i];
        if (r >= NVARS || (TYPE[r] != t1 && TYPE[r] != t2)) {
            snprintf(msg, sizeof msg, "%s: value reference %u is not of this type", fn, (unsigned)r);
            return fail(c, msg);
        }
        if (!((r >= VR_DRIVE && r <= VR_U64) || r == VR_W || r == VR_X0 || r == VR_N || r == VR_LABEL || r == VR_BLOB)) {
            snprintf(msg, sizeof msg, "%s: variable %u cannot be set", fn, (unsigned)r);
            return fail(c, msg);
        }
        if ((r == VR_X0 || r == VR_LABEL || r == VR_BLOB) && c->phase != ST_INSTANTIATED && c->phase != ST_INIT)
            return fail(c, "parameters can only be set before initialization ends");
        if (r == VR_N && c->phase != ST_INSTANTIATED)
            return fail(c, "the structural parameter n can only be set before initialization");
    }
    return fmi3OK;
}

#define GETTER(fn, T, t1, t2, field)                                                                     \
    fmi3Status fn(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr, T values[], size_t nv) { \
        Value buf[NMAX * NVARS];                                                                         \
        size_t i;                                                                                        \
        fmi3Status s;                                                                                    \
        if (nv > NMAX * NVARS) return fail((Instance *)inst, #fn ": too many values");                   \
        s = get_values((Instance *)inst, #fn, vr, nvr, t1, t2, buf, nv);                                 \
        if (s != fmi3OK) return s;                                                                       \
        for (i = 0; i < nv; i++) values[i] = (T)buf[i].field;                                            \
        return fmi3OK;                                                                                   \
    }
GETTER(fmi3GetFloat64, fmi3Float64, F64, F64, f)
GETTER(fmi3GetFloat32, fmi3Float32, F32, F32, f)
GETTER(fmi3GetInt8, fmi3Int8, I8, I8, i)
GETTER(fmi3GetUInt8, fmi3UInt8, U8, U8, i)
GETTER(fmi3GetInt16, fmi3Int16, I16, I16, i)
GETTER(fmi3GetUInt16, fmi3UInt16, U16, U16, i)
GETTER(fmi3GetInt32, fmi3Int32, I32, I32, i)
GETTER(fmi3GetUInt32, fmi3UInt32, U32, U32, i)
GETTER(fmi3GetInt64, fmi3Int64, I64, ENUM, i)
GETTER(fmi3GetUInt64, fmi3UInt64, U64, U64, u)
GETTER(fmi3GetBoolean, fmi3Boolean, BOOL, BOOL, i)

#define SETTER(fn, T, t1, t2, field)                                                                           \
    fmi3Status fn(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr, const T values[], size_t nv) { \
        Instance *c = (Instance *)inst;                                                                        \
        size_t i, k = 0;                                                                                       \
        fmi3Status s = check_set(c, #fn, vr, nvr, t1, t2, nv);                                                 \
        if (s != fmi3OK) return s;                                                                             \
        for (i = 0; i < nvr; i++) {                                                                            \
            if (vr[i] == VR_N && (values[k] < 1 || (uint64_t)values[k] > NMAX))                                \
                return fail(c, "n must be between 1 and 8");                                                   \
            if (vr[i] == VR_W) {                                                                               \
                c->m.w[0] = (double)values[k++];                                                               \
                c->m.w[1] = (double)values[k++];                                                               \
            } else {                                                                                           \
                c->m.v[vr[i]].field = values[k++];                                                             \
            }                                                                                                  \
        }                                                                                                      \
        return fmi3OK;                                                                                         \
    }
SETTER(fmi3SetFloat64, fmi3Float64, F64, F64, f)
SETTER(fmi3SetFloat32, fmi3Float32, F32, F32, f)
SETTER(fmi3SetInt8, fmi3Int8, I8, I8, i)
SETTER(fmi3SetUInt8, fmi3UInt8, U8, U8, i)
SETTER(fmi3SetInt16, fmi3Int16, I16, I16, i)
SETTER(fmi3SetUInt16, fmi3UInt16, U16, U16, i)
SETTER(fmi3SetInt32, fmi3Int32, I32, I32, i)
SETTER(fmi3SetUInt32, fmi3UInt32, U32, U32, i)
SETTER(fmi3SetInt64, fmi3Int64, I64, ENUM, i)
SETTER(fmi3SetUInt64, fmi3UInt64, U64, U64, u)
SETTER(fmi3SetBoolean, fmi3Boolean, BOOL, BOOL, i)

fmi3Status fmi3GetString(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr, fmi3String values[],
                         size_t nv) {
    size_t i;
    if (nv != nvr) return fail((Instance *)inst, "fmi3GetString: scalars only");
    for (i = 0; i < nvr; i++) {
        if (vr[i] != VR_LABEL) return fail((Instance *)inst, "fmi3GetString: not a String variable");
        values[i] = "typed";
    }
    return fmi3OK;
}
fmi3Status fmi3SetString(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr, const fmi3String values[],
                         size_t nv) {
    (void)values;
    return check_set((Instance *)inst, "fmi3SetString", vr, nvr, STR, STR, nv);
}
fmi3Status fmi3GetBinary(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr, size_t sizes[],
                         fmi3Binary values[], size_t nv) {
    static const fmi3Byte EMPTY[1] = {0};
    size_t i;
    if (nv != nvr) return fail((Instance *)inst, "fmi3GetBinary: scalars only");
    for (i = 0; i < nvr; i++) {
        if (vr[i] != VR_BLOB) return fail((Instance *)inst, "fmi3GetBinary: not a Binary variable");
        sizes[i] = 0;
        values[i] = EMPTY;
    }
    return fmi3OK;
}
fmi3Status fmi3SetBinary(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr, const size_t sizes[],
                         const fmi3Binary values[], size_t nv) {
    (void)sizes;
    (void)values;
    return check_set((Instance *)inst, "fmi3SetBinary", vr, nvr, BIN, BIN, nv);
}

fmi3Status fmi3EnterConfigurationMode(fmi3Instance c) { return fail((Instance *)c, "n is fixed"); }
fmi3Status fmi3ExitConfigurationMode(fmi3Instance c) { return fail((Instance *)c, "n is fixed"); }

/* ---- co-simulation ---- */
fmi3Status fmi3DoStep(fmi3Instance inst, fmi3Float64 t, fmi3Float64 h, fmi3Boolean noSetPrior,
                      fmi3Boolean *eventNeeded, fmi3Boolean *terminate, fmi3Boolean *earlyReturn,
                      fmi3Float64 *lastTime) {
    Instance *c = (Instance *)inst;
    const int64_t mode = c ? c->m.v[VR_MODE].i : 0;
    const double s = mode == 1 ? 1.0 : mode == 2 ? -1.0 : 0.0;
    (void)noSetPrior;
    if (do_step_checks(c, eventNeeded, terminate, earlyReturn) != fmi3OK) return fmi3Error;
    if (!(h > 0.0)) return fail(c, "fmi3DoStep: communication step size must be positive");
    if (mode < 1 || mode > 3) return fail(c, "fmi3DoStep: mode must be 1, 2 or 3");
    if (c->m.v[VR_ON].i)
        c->m.v[VR_X].f += h * (double)(float)c->m.v[VR_GAIN].f * (double)c->m.v[VR_DRIVE].i * s;
    c->m.v[VR_STEPS].i = (c->m.v[VR_STEPS].i + 1) & 0xFF;
    c->m.v[VR_TIME].f = t + h;
    if (lastTime) *lastTime = c->m.v[VR_TIME].f;
    return fmi3OK;
}
