//! Lowering the CPU priority (raising the nice value) of a process and every one of its threads,
//! so that on a machine with fewer cores than busy processes the scheduler serves others first.

use crate::error::{Error, Result};

/// The highest nice value (the lowest priority) Linux knows.
pub const NICE_MAX: i32 = 19;

/// Raises the nice value of every thread of process `pid` and of its descendants (a shell's
/// command, an adapter's workers) by `by` (capped at [`NICE_MAX`]); returns how many threads
/// were changed. Raising a nice value needs no privilege; lowering it again does, so this is
/// one-way for an ordinary user. On other systems than Linux it changes nothing and says so.
///
/// Errors: `Config` when the process is gone or a thread cannot be changed.
pub fn lower_priority(pid: u32, by: i32) -> Result<usize> {
    #[cfg(target_os = "linux")]
    {
        let (mut changed, children) = lower_threads(pid, by)?;
        for child in children {
            // A descendant that ended meanwhile is not an error.
            changed += lower_priority(child, by).unwrap_or(0);
        }
        Ok(changed)
    }
    #[cfg(not(target_os = "linux"))]
    {
        let _ = (pid, by);
        Err(Error::Config(
            "lowering a process's priority is implemented on Linux only".into(),
        ))
    }
}

/// [`lower_priority`] for the threads of `pid` alone, in one pass over them that also collects
/// their child processes (each thread's `children` list): (threads changed, children).
#[cfg(target_os = "linux")]
fn lower_threads(pid: u32, by: i32) -> Result<(usize, Vec<u32>)> {
    let tasks = std::fs::read_dir(format!("/proc/{pid}/task"))
        .map_err(|e| Error::Config(format!("process {pid}: {e}")))?;
    let (mut changed, mut children) = (0, Vec::new());
    for t in tasks.flatten() {
        let Some(tid) = t.file_name().to_str().and_then(|s| s.parse::<u32>().ok()) else {
            continue;
        };
        if let Ok(list) = std::fs::read_to_string(t.path().join("children")) {
            children.extend(
                list.split_whitespace()
                    .filter_map(|c| c.parse::<u32>().ok()),
            );
        }
        // A thread that ended since the listing is not an error.
        let Ok(now) = thread_nice(pid, tid) else {
            continue;
        };
        let target = (now + by).min(NICE_MAX);
        if target == now {
            continue;
        }
        set_nice(tid, target)
            .map_err(|e| Error::Config(format!("process {pid} thread {tid}: {e}")))?;
        changed += 1;
    }
    Ok((changed, children))
}

/// The nice value of thread `tid` of process `pid` (field 19 of its `stat`).
#[cfg(target_os = "linux")]
pub fn thread_nice(pid: u32, tid: u32) -> std::io::Result<i32> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/task/{tid}/stat"))?;
    // The command name (field 2) may hold spaces and parentheses: count from the last ')'.
    let after = stat.rsplit_once(')').map_or("", |(_, r)| r);
    after
        .split_whitespace()
        .nth(16)
        .and_then(|f| f.parse().ok())
        .ok_or_else(|| std::io::Error::other(format!("unreadable stat of thread {tid}")))
}

/// Sets the nice value of one thread (Linux: `setpriority(PRIO_PROCESS, tid, nice)`).
#[cfg(target_os = "linux")]
fn set_nice(tid: u32, nice: i32) -> std::io::Result<()> {
    // SAFETY: setpriority reads its three integer arguments only.
    let rc = unsafe { libc::setpriority(libc::PRIO_PROCESS, tid as libc::id_t, nice) };
    if rc == 0 {
        Ok(())
    } else {
        Err(std::io::Error::last_os_error())
    }
}

#[cfg(all(test, target_os = "linux"))]
mod tests {
    use super::*;

    #[test]
    fn every_thread_of_a_child_gets_the_higher_nice_value_and_it_stops_at_19() {
        // `sleep` has one thread; its nice starts at ours.
        let mut child = std::process::Command::new("sleep")
            .arg("5")
            .spawn()
            .unwrap();
        let pid = child.id();
        let before = thread_nice(pid, pid).unwrap();
        let by = 3.min(NICE_MAX - before);
        let changed = lower_priority(pid, by).unwrap();
        let after = thread_nice(pid, pid).unwrap();
        assert_eq!(after, before + by);
        assert_eq!(changed, usize::from(by > 0));
        lower_priority(pid, 100).unwrap();
        assert_eq!(thread_nice(pid, pid).unwrap(), NICE_MAX);
        child.kill().unwrap();
        child.wait().unwrap();
        let gone = lower_priority(pid, 1).unwrap_err().to_string();
        assert!(gone.contains(&format!("process {pid}")), "{gone}");
    }

    #[test]
    fn a_shell_and_the_command_it_started_are_both_lowered() {
        // `sh -c 'sleep 5; :'` cannot exec its command: sleep is its child.
        let mut sh = std::process::Command::new("sh")
            .args(["-c", "sleep 5; :"])
            .spawn()
            .unwrap();
        let pid = sh.id();
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(5);
        let kid = loop {
            let kids = std::fs::read_to_string(format!("/proc/{pid}/task/{pid}/children"));
            if let Some(k) = kids
                .ok()
                .and_then(|l| l.split_whitespace().next()?.parse().ok())
            {
                break k;
            }
            assert!(std::time::Instant::now() < deadline, "sh started no child");
            std::thread::sleep(std::time::Duration::from_millis(10));
        };
        let (sh_before, kid_before) = (
            thread_nice(pid, pid).unwrap(),
            thread_nice(kid, kid).unwrap(),
        );
        lower_priority(pid, 2).unwrap();
        assert_eq!(
            thread_nice(pid, pid).unwrap(),
            (sh_before + 2).min(NICE_MAX)
        );
        assert_eq!(
            thread_nice(kid, kid).unwrap(),
            (kid_before + 2).min(NICE_MAX)
        );
        let _ = std::process::Command::new("kill")
            .arg(kid.to_string())
            .status();
        sh.kill().unwrap();
        sh.wait().unwrap();
    }

    #[test]
    fn our_own_nice_value_is_read_as_the_kernel_reports_it() {
        // The independent reading: getpriority(2) of this thread.
        let tid = std::process::id();
        // SAFETY: getpriority reads its integer arguments only.
        let by_syscall = unsafe { libc::getpriority(libc::PRIO_PROCESS, tid as libc::id_t) };
        assert_eq!(thread_nice(tid, tid).unwrap(), by_syscall);
    }
}
