//! `hybsim sweep --shard` as a Slurm job array on a real single-node
//! cluster started on localhost (Debian's `slurm-wlm` and `munge`, installed
//! by `scripts/setup`): munged, slurmctld and slurmd run from a scratch
//! directory on free ports, are stopped by their pids, and every wait is
//! bounded; failures carry the daemons' logs. The merged shards must equal
//! the unsharded sweep byte for byte.

use std::net::TcpListener;
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use crate::util::{BIN, code, hybsim, stderr};

/// The daemons of one test cluster; killed (by pid) when dropped.
struct Cluster {
    dir: PathBuf,
    conf: PathBuf,
    children: Vec<(&'static str, Child)>,
}

impl Drop for Cluster {
    fn drop(&mut self) {
        // slurmd first, then the controller, then munged.
        for (_, c) in self.children.iter_mut().rev() {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

impl Cluster {
    /// The daemons' logs, for failure messages.
    fn logs(&self) -> String {
        let mut s = String::new();
        for f in [
            "ctld.log",
            "d.log",
            "munged.log",
            "munged.out",
            "ctld.out",
            "d.out",
        ] {
            let text = std::fs::read_to_string(self.dir.join(f)).unwrap_or_default();
            let tail: Vec<&str> = text.lines().rev().take(30).collect();
            s.push_str(&format!("--- {f} (last lines)\n"));
            for l in tail.iter().rev() {
                s.push_str(l);
                s.push('\n');
            }
        }
        s
    }

    fn slurm(&self, program: &str) -> Command {
        let mut c = Command::new(program);
        c.env("SLURM_CONF", &self.conf);
        c
    }

    fn spawn(&mut self, name: &'static str, mut cmd: Command) {
        let out = std::fs::File::create(self.dir.join(format!("{name}.out"))).unwrap();
        let child = cmd
            .stdin(Stdio::null())
            .stdout(out.try_clone().unwrap())
            .stderr(out)
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {name}: {e}"));
        self.children.push((name, child));
    }

    /// Waits (at most `limit`) until `ready` holds; panics with the logs.
    fn wait_for(&mut self, what: &str, limit: Duration, mut ready: impl FnMut(&Self) -> bool) {
        let start = Instant::now();
        while !ready(self) {
            let mut exited = None;
            for (name, c) in &mut self.children {
                if let Ok(Some(status)) = c.try_wait() {
                    exited = Some(format!("{name} exited ({status})"));
                }
            }
            if let Some(exited) = exited {
                panic!("{exited} while waiting for {what}\n{}", self.logs());
            }
            if start.elapsed() > limit {
                panic!(
                    "timed out after {limit:?} waiting for {what}\n{}",
                    self.logs()
                );
            }
            std::thread::sleep(Duration::from_millis(200));
        }
    }
}

fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

fn output_of(cmd: &mut Command) -> String {
    let out = cmd.output().unwrap_or_else(|e| panic!("{cmd:?}: {e}"));
    String::from_utf8_lossy(&out.stdout).trim().to_string()
}

fn id_of(flag: &str) -> u32 {
    output_of(Command::new("id").args([flag, "munge"]))
        .parse()
        .expect("the munge user exists (apt-get install munge)")
}

/// Starts munged, slurmctld and slurmd in `dir`.
fn start_cluster(dir: &Path) -> Cluster {
    for daemon in [
        "/usr/sbin/munged",
        "/usr/sbin/slurmctld",
        "/usr/sbin/slurmd",
    ] {
        assert!(
            Path::new(daemon).exists(),
            "{daemon} is missing: run scripts/setup (installs slurm-wlm and munge)"
        );
    }
    assert_eq!(
        output_of(Command::new("id").arg("-u")),
        "0",
        "the Slurm test starts daemons as root"
    );
    let munge = dir.join("munge");
    for d in ["state", "spool", "munge"] {
        std::fs::create_dir_all(dir.join(d)).unwrap();
    }
    // munged (the munge user) must reach its socket directory.
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(dir, std::fs::Permissions::from_mode(0o755)).unwrap();
    let (uid, gid) = (id_of("-u"), id_of("-g"));
    std::os::unix::fs::chown(&munge, Some(uid), Some(gid)).unwrap();
    let host = output_of(Command::new("hostname").arg("-s"));
    let cpus = std::thread::available_parallelism().map_or(1, |n| n.get());
    let d = dir.display();
    let conf = dir.join("slurm.conf");
    std::fs::write(
        &conf,
        format!(
            "ClusterName=hybsimtest
SlurmctldHost={host}
SlurmctldPort={}
SlurmdPort={}
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
AuthInfo=socket={d}/munge/sock
CredType=cred/munge
StateSaveLocation={d}/state
SlurmdSpoolDir={d}/spool
SlurmctldPidFile={d}/slurmctld.pid
SlurmdPidFile={d}/slurmd.pid
SlurmctldLogFile={d}/ctld.log
SlurmdLogFile={d}/d.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
ReturnToService=2
NodeName={host} CPUs={cpus} RealMemory=1000 State=UNKNOWN
PartitionName=debug Nodes={host} Default=YES MaxTime=INFINITE State=UP
",
            free_port(),
            free_port()
        ),
    )
    .unwrap();
    let mut cluster = Cluster {
        dir: dir.to_path_buf(),
        conf: conf.clone(),
        children: Vec::new(),
    };
    let mut munged = Command::new("/usr/sbin/munged");
    munged
        .arg("-F")
        .arg(format!("--socket={}", munge.join("sock").display()))
        .arg(format!("--pid-file={}", munge.join("pid").display()))
        .arg(format!("--log-file={}", dir.join("munged.log").display()))
        .arg(format!("--seed-file={}", munge.join("seed").display()))
        .uid(uid)
        .gid(gid);
    cluster.spawn("munged", munged);
    cluster.wait_for("munged's socket", Duration::from_secs(20), |c| {
        c.dir.join("munge/sock").exists()
    });
    let mut ctld = cluster.slurm("/usr/sbin/slurmctld");
    ctld.args(["-D", "-i", "-f"]).arg(&conf);
    cluster.spawn("ctld", ctld);
    let mut slurmd = cluster.slurm("/usr/sbin/slurmd");
    slurmd.args(["-D", "-f"]).arg(&conf);
    cluster.spawn("d", slurmd);
    cluster.wait_for("the node to be idle", Duration::from_secs(60), |c| {
        output_of(c.slurm("sinfo").args(["-h", "-o", "%t"])) == "idle"
    });
    cluster
}

const MODEL: &str = "model ball
param g = 9.81, lambda = 0.8
state h ~ uniform(0.5, 1.5), v = 0
flow { h' = v; v' = -g } in h >= 0
jump impact when h <= 0 && v <= 0 { v+ = -lambda * v }
metric bounces = count(impact), hmax = max(h), e = mean(0.5*v^2 + g*h)
sim { T = 2; dt_out = 0.01 }
";

const SWEEP: &str = "--grid lambda=0.6:0.1:0.9 --grid g=[9.81,3.7] --runs 3 --seed 7 -q";

#[test]
fn a_slurm_job_array_of_shards_merges_into_the_unsharded_sweep() {
    let scratch = tempfile::tempdir().unwrap();
    let dir = scratch.path();
    std::fs::write(dir.join("ball.hyb"), MODEL).unwrap();
    let cluster = start_cluster(dir);
    std::fs::write(
        dir.join("job.sh"),
        format!(
            "#!/bin/bash\nexec {BIN} sweep ball.hyb {SWEEP} --threads 1 \
             --shard \"$SLURM_ARRAY_TASK_ID/$SLURM_ARRAY_TASK_COUNT\" \
             -o \"shards/$SLURM_ARRAY_TASK_ID\"\n"
        ),
    )
    .unwrap();
    let mut sbatch = cluster.slurm("sbatch");
    sbatch
        .args(["--wait", "--array=1-3", "--chdir"])
        .arg(dir)
        .arg(format!("--output={}/task_%a.out", dir.display()))
        .arg(dir.join("job.sh"))
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    let mut job = sbatch.spawn().expect("sbatch runs");
    let start = Instant::now();
    let status = loop {
        if let Some(s) = job.try_wait().unwrap() {
            break s;
        }
        if start.elapsed() > Duration::from_secs(180) {
            let _ = job.kill();
            let _ = job.wait();
            panic!("the job array did not finish in 180 s\n{}", cluster.logs());
        }
        std::thread::sleep(Duration::from_millis(200));
    };
    let tasks: String = (1..=3)
        .map(|k| std::fs::read_to_string(dir.join(format!("task_{k}.out"))).unwrap_or_default())
        .collect();
    assert!(
        status.success(),
        "sbatch: {status}\n{tasks}\n{}",
        cluster.logs()
    );
    drop(cluster);

    let merged = hybsim(
        dir,
        &[
            "sweep", "--merge", "shards/1", "shards/2", "shards/3", "-o", "merged",
        ],
    );
    assert_eq!(code(&merged), 0, "{}\n{tasks}", stderr(&merged));
    let mut args: Vec<&str> = vec!["sweep", "ball.hyb"];
    args.extend(SWEEP.split(' '));
    args.extend(["-o", "whole"]);
    let whole = hybsim(dir, &args);
    assert_eq!(code(&whole), 0, "{}", stderr(&whole));
    let files = |d: &str| -> Vec<(String, Vec<u8>)> {
        let mut v: Vec<_> = std::fs::read_dir(dir.join(d))
            .unwrap()
            .map(|e| {
                let e = e.unwrap();
                (
                    e.file_name().to_string_lossy().into_owned(),
                    std::fs::read(e.path()).unwrap(),
                )
            })
            .collect();
        v.sort();
        v
    };
    let whole = files("whole");
    assert_eq!(
        whole.len(),
        8,
        "sweep.json, runs and points as CSV and Parquet, and three plots"
    );
    assert!(
        whole == files("merged"),
        "merged shards differ from the unsharded sweep"
    );
}
