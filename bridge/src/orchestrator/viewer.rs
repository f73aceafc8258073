//! The viewer process of `koopbridge run --view` / `--record-view`: `python -m koopbridge.view`
//! started beside the run and awaited by its liveliness token, released at the end so that it
//! writes `view.rrd`; a viewer that does not start, or dies, is a warning and never the run's end.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use super::program::external_program;
use crate::client::Liveliness;
use crate::keyexpr::Role;
use crate::procs::{tail, ChildProc};

/// The viewer's participant id (`…/alive/viewer/view`).
pub const VIEWER_ID: &str = "view";

/// Where the live view is shown.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ViewMode {
    /// Rerun's web viewer, served on a local port (open its address in a browser).
    Web,
    /// Rerun's desktop viewer (needs a display).
    Native,
    /// No viewer: the view is only recorded (`view.rrd`).
    Record,
}

impl ViewMode {
    /// `--view`'s default: the desktop viewer where there is a display, else the web viewer.
    pub fn auto() -> Self {
        let has = |v: &str| std::env::var_os(v).is_some_and(|s| !s.is_empty());
        if has("DISPLAY") || has("WAYLAND_DISPLAY") {
            ViewMode::Native
        } else {
            ViewMode::Web
        }
    }

    fn flag(self) -> Option<&'static str> {
        match self {
            ViewMode::Web => Some("--web"),
            ViewMode::Native => Some("--native"),
            ViewMode::Record => None,
        }
    }
}

/// How a run is viewed.
#[derive(Clone, Debug)]
pub struct ViewOptions {
    /// Where it is shown.
    pub mode: ViewMode,
    /// The web viewer's port (`--view web`; default: a free one).
    pub web_port: Option<u16>,
    /// MP4s of these references' loops (`--video 0,3`; a `[control]` loop is reference 0),
    /// written into `videos/` beside `view.rrd`.
    pub video: Option<String>,
}

/// By how much the viewer's nice value is raised above the run's.
const VIEWER_NICE: i32 = 10;
/// How long the viewer is given to subscribe (importing Rerun takes a few seconds).
const READY: Duration = Duration::from_secs(60);
/// How long the viewer is given to write `view.rrd` once the run has ended (and, with
/// `--video`, to render the frames it has not rendered yet).
const FLUSH: Duration = Duration::from_secs(60);
const FLUSH_WITH_VIDEO: Duration = Duration::from_secs(1800);

/// The running viewer.
pub struct ViewerProc {
    child: ChildProc,
    rrd: PathBuf,
    out_dir: PathBuf,
    video: bool,
}

/// What `python -m koopbridge.view` is started with to follow session `session` at `endpoint`
/// and record into `rrd`.
pub fn viewer_args(opts: &ViewOptions, session: &str, endpoint: &str, rrd: &Path) -> Vec<String> {
    let mut a: Vec<String> = [
        "-m",
        "koopbridge.view",
        "--session",
        session,
        "--id",
        VIEWER_ID,
        "--connect",
        endpoint,
        "--save",
    ]
    .map(String::from)
    .to_vec();
    a.push(rrd.display().to_string());
    a.push("--stdin-lifeline".into());
    if let Some(f) = opts.mode.flag() {
        a.push(f.into());
    }
    if let (ViewMode::Web, Some(p)) = (opts.mode, opts.web_port) {
        a.extend(["--web-port".into(), p.to_string()]);
    }
    if let Some(refs) = &opts.video {
        a.extend(["--video".into(), refs.clone()]);
    }
    a
}

impl ViewerProc {
    /// Starts the viewer of session `session` (reachable at `endpoint`) recording into
    /// `out_dir/view.rrd` (`{python}` as for the scenario's commands in folder `base`), and waits
    /// until it subscribes. `None` (with `warn` told why and what to do) when it cannot start: the
    /// run goes on without it.
    pub fn start(
        opts: &ViewOptions,
        session: &str,
        endpoint: &str,
        out_dir: &Path,
        base: &Path,
        live: &Liveliness,
        warn: &mut dyn FnMut(&str),
    ) -> Option<Self> {
        let rrd = out_dir.join("view.rrd");
        let python = external_program("{python}", base);
        let log = out_dir.join("logs").join("viewer.log");
        let args = viewer_args(opts, session, endpoint, &rrd);
        let mut child = match ChildProc::spawn("the viewer", &python, &args, &log) {
            Ok(c) => c,
            Err(e) => {
                warn(&format!("{e}; the run goes on without a view"));
                return None;
            }
        };
        // The run comes first: on a busy machine the viewer lags rather than slows the loop.
        if let Err(e) = crate::priority::lower_priority(child.id(), VIEWER_NICE) {
            tracing::debug!("the viewer's priority could not be lowered: {e}");
        }
        let who = [(Role::Viewer, VIEWER_ID.to_string())];
        let deadline = Instant::now() + READY;
        loop {
            if live.wait_for(&who, Duration::from_millis(200)).is_ok() {
                return Some(ViewerProc {
                    child,
                    rrd,
                    out_dir: out_dir.to_path_buf(),
                    video: opts.video.is_some(),
                });
            }
            let why = match child.exited() {
                Some(_) => "it exited",
                None if Instant::now() > deadline => "it did not subscribe within 60 s",
                None => continue,
            };
            child.kill();
            warn(&format!(
                "the viewer could not start ({why}); the run goes on without it. {}\n\
                 Without a display use `--view web` (a local port) or `--record-view` (only \
                 view.rrd). End of {}:\n{}",
                if opts.mode == ViewMode::Native {
                    "The desktop viewer needs a display."
                } else {
                    ""
                },
                log.display(),
                tail(&log, 1500)
            ));
            return None;
        }
    }

    /// The MP4s the viewer wrote (`videos/*.mp4`), by name.
    pub fn videos(out_dir: &Path) -> Vec<PathBuf> {
        let mut v: Vec<PathBuf> = std::fs::read_dir(out_dir.join("videos"))
            .into_iter()
            .flatten()
            .flatten()
            .map(|e| e.path())
            .filter(|p| p.extension().is_some_and(|e| e == "mp4"))
            .filter(|p| !p.to_string_lossy().ends_with(".part.mp4"))
            .collect();
        v.sort();
        v
    }

    /// The web viewer's address, once the viewer has written it (`view.json`).
    pub fn web_url(&self) -> Option<String> {
        let text = std::fs::read_to_string(self.out_dir.join("view.json")).ok()?;
        let v: serde_json::Value = serde_json::from_str(&text).ok()?;
        v.get("web").and_then(|u| u.as_str()).map(str::to_string)
    }

    /// Ends the view: releases the viewer (it writes `view.rrd` and exits) and waits for it.
    /// The recording's path, or the warning of a viewer that died during the run or wrote
    /// nothing.
    pub fn finish(mut self) -> std::result::Result<PathBuf, String> {
        if let Some(msg) = self.child.exited() {
            return Err(format!(
                "the viewer died during the run; the run went on without it: {msg}"
            ));
        }
        self.child.release();
        let grace = if self.video { FLUSH_WITH_VIDEO } else { FLUSH };
        self.child.reap(Instant::now() + grace);
        match self.rrd.is_file() {
            true => Ok(self.rrd),
            false => Err(format!(
                "the viewer wrote no {}; see {}",
                self.rrd.display(),
                self.out_dir.join("logs").join("viewer.log").display()
            )),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_viewer_is_told_the_session_the_endpoint_and_where_to_record() {
        let o = ViewOptions {
            mode: ViewMode::Web,
            web_port: Some(9090),
            video: None,
        };
        let a = viewer_args(&o, "s1", "tcp/127.0.0.1:7000", Path::new("out/view.rrd"));
        let line = a.join(" ");
        assert!(
            line.starts_with("-m koopbridge.view --session s1 --id view"),
            "{line}"
        );
        assert!(
            line.contains("--connect tcp/127.0.0.1:7000 --save out/view.rrd"),
            "{line}"
        );
        assert!(
            line.ends_with("--stdin-lifeline --web --web-port 9090"),
            "{line}"
        );
        let r = ViewOptions {
            mode: ViewMode::Record,
            web_port: Some(9090),
            video: Some("0,3".into()),
        };
        let a = viewer_args(&r, "s1", "e", Path::new("v.rrd"));
        assert!(!a.iter().any(|s| s.starts_with("--web")), "{a:?}");
        assert!(a.ends_with(&["--video".into(), "0,3".into()]), "{a:?}");
    }
}
