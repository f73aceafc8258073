//! Network namespaces that a test makes itself (root only): namespaces joined by veth links with
//! addresses in 127.0.0.0/8 (`route_localnet` set inside each), processes started inside one,
//! links cut and restored; everything removed when the [`Net`] is dropped.

use std::path::Path;
use std::process::Command;

use bridge::procs::ChildProc;

/// The namespaces and links of one test.
pub struct Net {
    /// Short unique prefix of every name (interface names have at most 15 characters).
    prefix: String,
    namespaces: Vec<String>,
    links: usize,
}

/// Runs `ip args…`; the error quotes its standard error.
fn ip(args: &[&str]) -> Result<(), String> {
    let o = Command::new("ip")
        .args(args)
        .output()
        .map_err(|e| format!("ip {}: {e}", args.join(" ")))?;
    if o.status.success() {
        Ok(())
    } else {
        Err(format!(
            "ip {}: {}",
            args.join(" "),
            String::from_utf8_lossy(&o.stderr).trim()
        ))
    }
}

impl Net {
    /// An empty set, or why namespaces cannot be made here (not root, no `ip`, no permission):
    /// the test then skips, saying so.
    pub fn new(tag: &str) -> Result<Self, String> {
        let prefix = format!(
            "kb{}{}",
            &tag[..tag.len().min(2)],
            std::process::id() % 100_000
        );
        let probe = format!("{prefix}-probe");
        ip(&["netns", "add", &probe])?;
        ip(&["netns", "del", &probe])?;
        Ok(Net {
            prefix,
            namespaces: Vec::new(),
            links: 0,
        })
    }

    /// Makes namespace `name` (loopback up, `route_localnet` on) and returns its full name.
    pub fn ns(&mut self, name: &str) -> Result<String, String> {
        let full = format!("{}-{name}", self.prefix);
        ip(&["netns", "add", &full])?;
        self.namespaces.push(full.clone());
        ip(&["-n", &full, "link", "set", "lo", "up"])?;
        let o = Command::new("ip")
            .args(["netns", "exec", &full, "sh", "-c"])
            .arg("echo 1 > /proc/sys/net/ipv4/conf/all/route_localnet")
            .status()
            .map_err(|e| e.to_string())?;
        if !o.success() {
            return Err(format!("route_localnet in {full}"));
        }
        Ok(full)
    }

    /// Joins namespaces `a` and `b` with a veth link, `a_addr`/24 on `a`'s end and `b_addr`/24 on
    /// `b`'s; returns the interface names (on `a`, on `b`).
    pub fn link(
        &mut self,
        a: &str,
        a_addr: &str,
        b: &str,
        b_addr: &str,
    ) -> Result<(String, String), String> {
        self.links += 1;
        let (ia, ib) = (
            format!("{}v{}a", self.prefix, self.links),
            format!("{}v{}b", self.prefix, self.links),
        );
        ip(&[
            "link", "add", &ia, "netns", a, "type", "veth", "peer", "name", &ib, "netns", b,
        ])?;
        for (ns, i, addr) in [(a, &ia, a_addr), (b, &ib, b_addr)] {
            ip(&["-n", ns, "addr", "add", &format!("{addr}/24"), "dev", i])?;
            ip(&["-n", ns, "link", "set", i, "up"])?;
        }
        Ok((ia, ib))
    }

    /// Takes interface `dev` of namespace `ns` down (`up = false`: the link is cut, nothing is
    /// sent on it any more, no connection is reset) or up again.
    pub fn set_link(&self, ns: &str, dev: &str, up: bool) {
        ip(&["-n", ns, "link", "set", dev, if up { "up" } else { "down" }]).unwrap();
    }

    /// Starts `exe args…` with extra environment `env` inside namespace `ns` (`ip netns exec`
    /// runs it in place, so the child is the program itself, with standard input as its
    /// lifeline).
    pub fn spawn(
        &self,
        ns: &str,
        name: &str,
        exe: &Path,
        args: &[&str],
        env: &[(&str, &str)],
        log: &Path,
    ) -> ChildProc {
        let mut a: Vec<String> = vec!["netns".into(), "exec".into(), ns.into()];
        a.push(exe.display().to_string());
        a.extend(args.iter().map(|s| s.to_string()));
        ChildProc::spawn_env(name, Path::new("ip"), &a, env, log).unwrap()
    }
}

impl Net {
    /// Starts `koopbridge router` (the binary `exe`) in namespace `ns` on port 7447 of every
    /// address with the Zenoh config `cfg`, and returns once it listens (clients that find no
    /// router exit at once, so start them after this).
    pub fn spawn_router(&self, ns: &str, exe: &Path, cfg: &str, log: &Path) -> ChildProc {
        let mut router = self.spawn(
            ns,
            "router",
            exe,
            &[
                "router",
                "--listen",
                "tcp/0.0.0.0:7447",
                "--zenoh-config",
                cfg,
                "--stdin-lifeline",
            ],
            &[],
            log,
        );
        let t = std::time::Instant::now();
        while !std::fs::read_to_string(log).is_ok_and(|l| l.contains("listening on")) {
            if let Some(m) = router.exited() {
                panic!("the router ended before listening: {m}");
            }
            assert!(t.elapsed() < super::READY, "the router never listened");
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
        router
    }
}

impl Drop for Net {
    fn drop(&mut self) {
        for ns in self.namespaces.drain(..) {
            let _ = ip(&["netns", "del", &ns]);
        }
    }
}
