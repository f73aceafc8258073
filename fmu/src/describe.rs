//! `modelDescription.xml` for FMI 3.0 and FMI 2.0, generated from the [`Layout`] the binary
//! serves (so value references, names, ranges and start values cannot drift apart).

use std::fmt::Write;

use crate::layout::{Causality, Layout, Role, Variable};
use crate::settings::ControllerFile;

/// The FMI version of an export.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FmiVersion {
    /// FMI 3.0 (binaries/x86_64-linux/).
    V3,
    /// FMI 2.0 (binaries/linux64/).
    V2,
}

impl FmiVersion {
    /// The platform folder of the Linux x86-64 binary.
    pub fn platform(self) -> &'static str {
        match self {
            FmiVersion::V3 => "x86_64-linux",
            FmiVersion::V2 => "linux64",
        }
    }
}

/// What the description says about the FMU besides its variables.
pub struct Header<'a> {
    /// `modelIdentifier` (the binary's file name without `.so`).
    pub model_identifier: &'a str,
    /// `modelName`.
    pub model_name: &'a str,
    /// `description`.
    pub description: &'a str,
    /// `generationTool`.
    pub generation_tool: &'a str,
}

/// XML-escapes `s` for an attribute value.
pub fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// A real as the model description writes it (`INF`, `-INF` for the infinities).
fn real(v: f64) -> String {
    if v == f64::INFINITY {
        "INF".into()
    } else if v == f64::NEG_INFINITY {
        "-INF".into()
    } else {
        format!("{v:?}")
    }
}

/// The model description of `layout` (from `file`) for `version`.
pub fn model_description(
    version: FmiVersion,
    layout: &Layout,
    file: &ControllerFile,
    h: &Header,
) -> String {
    let mut x = String::new();
    let v3 = version == FmiVersion::V3;
    let _ = writeln!(x, r#"<?xml version="1.0" encoding="UTF-8"?>"#);
    let token_attr = if v3 { "instantiationToken" } else { "guid" };
    let _ = writeln!(
        x,
        r#"<fmiModelDescription fmiVersion="{}" modelName="{}" {token_attr}="{}" description="{}" generationTool="{}" variableNamingConvention="flat"{}>"#,
        if v3 { "3.0" } else { "2.0" },
        escape(h.model_name),
        escape(&file.token),
        escape(h.description),
        escape(h.generation_tool),
        if v3 {
            ""
        } else {
            r#" numberOfEventIndicators="0""#
        },
    );
    if v3 {
        let _ = writeln!(
            x,
            r#"  <CoSimulation modelIdentifier="{}" canHandleVariableCommunicationStepSize="true" canBeInstantiatedOnlyOncePerProcess="false" canGetAndSetFMUState="false" canSerializeFMUState="false" providesDirectionalDerivatives="false" providesAdjointDerivatives="false" hasEventMode="false" providesIntermediateUpdate="false" canReturnEarlyAfterIntermediateUpdate="false"/>"#,
            escape(h.model_identifier)
        );
    } else {
        let _ = writeln!(
            x,
            r#"  <CoSimulation modelIdentifier="{}" canHandleVariableCommunicationStepSize="true" canBeInstantiatedOnlyOncePerProcess="false" canNotUseMemoryManagementFunctions="true" canGetAndSetFMUstate="false" canSerializeFMUstate="false" providesDirectionalDerivative="false"/>"#,
            escape(h.model_identifier)
        );
    }
    let mut units: Vec<&str> = Vec::new();
    for v in &layout.variables {
        if let Some(u) = v.unit.as_deref() {
            if (v3 || v.role != Role::Time) && !units.contains(&u) {
                units.push(u);
            }
        }
    }
    if !units.is_empty() {
        let _ = writeln!(x, "  <UnitDefinitions>");
        for u in &units {
            let _ = writeln!(x, r#"    <Unit name="{}"/>"#, escape(u));
        }
        let _ = writeln!(x, "  </UnitDefinitions>");
    }
    let _ = writeln!(
        x,
        r#"  <LogCategories>
    <Category name="logStatusWarning" description="warnings (e.g. a communication step that is not the model's sampling period)"/>
    <Category name="logStatusError" description="errors: bad inputs or parameters, a failed solve, missing resources"/>
    <Category name="logInfo" description="information (with debug logging on)"/>
  </LogCategories>"#
    );
    let _ = writeln!(
        x,
        r#"  <DefaultExperiment startTime="0" stepSize="{}"/>"#,
        real(file.dt)
    );
    let _ = writeln!(x, "  <ModelVariables>");
    let vars: Vec<&Variable> = layout
        .variables
        .iter()
        .filter(|v| v3 || v.role != Role::Time)
        .collect();
    for v in &vars {
        if v3 {
            variable3(&mut x, v);
        } else {
            variable2(&mut x, v);
        }
    }
    let _ = writeln!(x, "  </ModelVariables>");
    let _ = writeln!(x, "  <ModelStructure>");
    let outputs: Vec<&&Variable> = vars
        .iter()
        .filter(|v| v.causality == Causality::Output)
        .collect();
    if v3 {
        for v in &outputs {
            let _ = writeln!(
                x,
                r#"    <Output valueReference="{}" dependencies=""/>"#,
                v.vr
            );
        }
        for v in &outputs {
            let _ = writeln!(x, r#"    <InitialUnknown valueReference="{}"/>"#, v.vr);
        }
    } else {
        // FMI 2 refers to variables by their 1-based index in ModelVariables.
        let index = |vr: u32| {
            vars.iter()
                .position(|w| w.vr == vr)
                .map(|i| i + 1)
                .unwrap_or(0)
        };
        let _ = writeln!(x, "    <Outputs>");
        for v in &outputs {
            let _ = writeln!(
                x,
                r#"      <Unknown index="{}" dependencies=""/>"#,
                index(v.vr)
            );
        }
        let _ = writeln!(x, "    </Outputs>");
        let _ = writeln!(x, "    <InitialUnknowns>");
        for v in &outputs {
            let _ = writeln!(x, r#"      <Unknown index="{}"/>"#, index(v.vr));
        }
        let _ = writeln!(x, "    </InitialUnknowns>");
    }
    let _ = writeln!(x, "  </ModelStructure>");
    let _ = writeln!(x, "</fmiModelDescription>");
    x
}

fn causality_name(c: Causality) -> &'static str {
    match c {
        Causality::Independent => "independent",
        Causality::Input => "input",
        Causality::Output => "output",
        Causality::Parameter => "parameter",
    }
}

fn variability(v: &Variable) -> &'static str {
    match (v.causality, v.integer) {
        (Causality::Parameter, _) => "fixed",
        (_, true) => "discrete",
        _ => "continuous",
    }
}

fn attrs(v: &Variable) -> String {
    let mut a = String::new();
    if let Some(u) = &v.unit {
        let _ = write!(a, r#" unit="{}""#, escape(u));
    }
    if let Some(m) = v.min {
        let _ = write!(a, r#" min="{}""#, number(v, m));
    }
    if let Some(m) = v.max {
        let _ = write!(a, r#" max="{}""#, number(v, m));
    }
    if let Some(s) = v.start {
        let _ = write!(a, r#" start="{}""#, number(v, s));
    }
    a
}

fn number(v: &Variable, x: f64) -> String {
    if v.integer {
        format!("{}", x as i64)
    } else {
        real(x)
    }
}

fn initial(v: &Variable) -> &'static str {
    match v.causality {
        Causality::Parameter => r#" initial="exact""#,
        Causality::Output => r#" initial="calculated""#,
        _ => "",
    }
}

fn variable3(x: &mut String, v: &Variable) {
    let ty = if v.integer { "Int32" } else { "Float64" };
    let mut a = attrs(v);
    if v.role == Role::Time {
        a = String::new();
        if let Some(u) = &v.unit {
            a = format!(r#" unit="{}""#, escape(u));
        }
    }
    let _ = writeln!(
        x,
        r#"    <{ty} name="{}" valueReference="{}" description="{}" causality="{}" variability="{}"{}{a}/>"#,
        escape(&v.name),
        v.vr,
        escape(&v.description),
        causality_name(v.causality),
        variability(v),
        initial(v),
    );
}

fn variable2(x: &mut String, v: &Variable) {
    let ty = if v.integer { "Integer" } else { "Real" };
    let _ = writeln!(
        x,
        r#"    <ScalarVariable name="{}" valueReference="{}" description="{}" causality="{}" variability="{}"{}>
      <{ty}{}/>
    </ScalarVariable>"#,
        escape(&v.name),
        v.vr,
        escape(&v.description),
        causality_name(v.causality),
        variability(v),
        initial(v),
        attrs(v),
    );
}
