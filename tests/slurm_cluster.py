"""A single-node SLURM cluster for the tests, from Debian's ``slurm-wlm`` and ``munge``.

Everything lives in one temporary folder: the munge key and socket, ``slurm.conf``, the
controller's state, the node's spool, the daemons' logs and pid files. The daemons listen on
loopback ports chosen free at start, run in the foreground as children of the test process
(no systemd), and are stopped by process id. Clients find the cluster through ``SLURM_CONF``
(:attr:`LocalSlurm.env`), so a machine's own SLURM, if any, is neither used nor disturbed. The
executor plugin's job step starts ``srun`` with only a few ``SLURM_*`` variables (not
``SLURM_CONF``), as a real cluster's clients read ``/etc/slurm/slurm.conf`` or fetch the
configuration from the controller; so the clients are reached through wrappers in ``bin/``, first
on ``PATH``, that set ``SLURM_CONF`` themselves.

No accounting (``accounting_storage/none``, ``jobacct_gather/none``): ``sacct`` has nothing to
report, so Snakemake's executor plugin must query ``squeue``, which shows finished jobs for
``MinJobAge`` seconds. No cgroups (``proctrack/linuxproc``, ``task/none``), which a container
rarely offers; memory and cores are still allocated per job (``select/cons_tres``,
``CR_CPU_Memory``), so a job asking for more than the node has is refused.
"""

from __future__ import annotations

import os
import re
import shutil
import socket
import subprocess
import time
from pathlib import Path

DAEMONS = ("munged", "mungekey", "slurmctld", "slurmd", "sbatch", "squeue", "sinfo", "scontrol")
CLIENTS = ("sbatch", "srun", "squeue", "sinfo", "scontrol", "scancel", "sacct", "salloc")


def missing_reason() -> str | None:
    """Why a local cluster cannot be started here, or ``None`` when it can."""
    missing = [d for d in DAEMONS if shutil.which(d) is None and not Path("/usr/sbin", d).exists()]
    if missing:
        return (f"SLURM test cluster: {', '.join(missing)} not installed (Debian packages slurm-wlm and munge; "
                "tools/bootstrap.sh installs them when run as root)")
    if os.geteuid() != 0:
        return "SLURM test cluster: slurmd must run as root to start jobs (run the tests as root, as CI does)"
    return None


def _exe(name: str) -> str:
    return shutil.which(name) or str(Path("/usr/sbin", name))


def _free_ports(n: int) -> list[int]:
    socks = []
    try:
        for _ in range(n):
            s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            s.bind(("127.0.0.1", 0))
            socks.append(s)
        return [s.getsockname()[1] for s in socks]
    finally:
        for s in socks:
            s.close()


def _node_hardware() -> tuple[int, int]:
    """CPUs and memory (MB) of this machine as slurmd reports them (``slurmd -C``)."""
    out = subprocess.run([_exe("slurmd"), "-C"], capture_output=True, text=True, check=True).stdout
    cpus = int(re.search(r"\bCPUs=(\d+)", out).group(1))
    mem = int(re.search(r"\bRealMemory=(\d+)", out).group(1))
    return cpus, mem


class LocalSlurm:
    """A controller and one node (``localhost``) started in ``root``; :meth:`stop` ends them."""

    def __init__(self, root: Path, partition: str = "debug") -> None:
        self.root = Path(root)
        self.partition = partition
        self.procs: dict[str, subprocess.Popen] = {}
        self.conf = self.root / "slurm.conf"
        self.bin = self.root / "bin"
        self.env = {**os.environ, "SLURM_CONF": str(self.conf),
                    "PATH": f"{self.bin}{os.pathsep}{os.environ.get('PATH', '')}"}
        for var in [k for k in self.env if k.startswith(("SLURM_", "SBATCH_", "SQUEUE_", "SRUN_"))]:
            if var != "SLURM_CONF":
                del self.env[var]

    # -- set-up -----------------------------------------------------------------------------
    def _write_config(self) -> None:
        r = self.root
        for d in ("munge", "state", "spool", "log", "bin"):
            (r / d).mkdir(parents=True, exist_ok=True)
        (r / "munge").chmod(0o755)
        for name in CLIENTS:
            if real := shutil.which(name):
                w = self.bin / name
                w.write_text(f'#!/bin/sh\nSLURM_CONF={self.conf} exec {real} "$@"\n')
                w.chmod(0o755)
        self.munge_socket = r / "munge" / "munge.socket"
        key = r / "munge" / "munge.key"
        subprocess.run([_exe("mungekey"), "--create", f"--keyfile={key}", "--force"], check=True,
                       capture_output=True)
        key.chmod(0o600)
        ctld_port, node_port = _free_ports(2)
        cpus, mem = _node_hardware()
        self.cpus = cpus
        # leave the system some memory; the rules ask for at most a few GB
        self.mem_mb = max(1000, int(mem * 0.8))
        self.conf.write_text("\n".join([
            "ClusterName=huefringe-test",
            "SlurmctldHost=localhost(127.0.0.1)",
            f"SlurmctldPort={ctld_port}",
            f"SlurmdPort={node_port}",
            "SlurmUser=root",
            "SlurmdUser=root",
            "AuthType=auth/munge",
            "CredType=cred/munge",
            f"AuthInfo=socket={self.munge_socket}",
            f"StateSaveLocation={r / 'state'}",
            f"SlurmdSpoolDir={r / 'spool'}",
            f"SlurmctldPidFile={r / 'slurmctld.pid'}",
            f"SlurmdPidFile={r / 'slurmd.pid'}",
            f"SlurmctldLogFile={r / 'log' / 'slurmctld.log'}",
            f"SlurmdLogFile={r / 'log' / 'slurmd.log'}",
            "SlurmctldDebug=info",
            "SlurmdDebug=info",
            "ProctrackType=proctrack/linuxproc",
            "TaskPlugin=task/none",
            "JobAcctGatherType=jobacct_gather/none",
            "AccountingStorageType=accounting_storage/none",
            "JobCompType=jobcomp/none",
            "SchedulerType=sched/builtin",
            "SelectType=select/cons_tres",
            "SelectTypeParameters=CR_CPU_Memory",
            "MpiDefault=none",
            "ReturnToService=2",
            # finished jobs stay visible to squeue this long: the plugin's status source here
            "MinJobAge=3600",
            "InactiveLimit=0",
            "KillWait=5",
            "SlurmdTimeout=300",
            f"NodeName=localhost NodeAddr=127.0.0.1 NodeHostname=localhost CPUs={cpus} RealMemory={self.mem_mb} State=UNKNOWN",
            f"PartitionName={self.partition} Nodes=localhost Default=YES MaxTime=INFINITE State=UP",
            "",
        ]))

    def _spawn(self, name: str, argv: list[str]) -> None:
        log = open(self.root / "log" / f"{name}.out", "ab")
        self.procs[name] = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                            env=self.env, start_new_session=True)
        log.close()

    def _wait(self, what: str, ok, timeout: float = 60.0) -> None:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            for name, p in self.procs.items():
                if p.poll() is not None:
                    raise RuntimeError(f"{name} exited ({p.returncode}) while waiting for {what}:\n{self.logs()}")
            if ok():
                return
            time.sleep(0.5)
        raise RuntimeError(f"timed out waiting for {what}:\n{self.logs()}")

    def run(self, *argv: str, check: bool = False) -> subprocess.CompletedProcess:
        return subprocess.run([_exe(argv[0]), *argv[1:]], capture_output=True, text=True, env=self.env,
                              check=check, timeout=60)

    def start(self) -> LocalSlurm:
        self._write_config()
        r = self.root
        self._spawn("munged", [_exe("munged"), "--foreground", "--force", f"--socket={self.munge_socket}",
                               f"--key-file={r / 'munge' / 'munge.key'}", f"--pid-file={r / 'munge' / 'munged.pid'}",
                               f"--log-file={r / 'log' / 'munged.log'}", f"--seed-file={r / 'munge' / 'munged.seed'}"])
        self._wait("munged", self.munge_socket.exists)
        self._spawn("slurmctld", [_exe("slurmctld"), "-D", "-i", "-f", str(self.conf)])
        self._wait("slurmctld", lambda: self.run("scontrol", "ping").returncode == 0
                   and "UP" in self.run("scontrol", "ping").stdout)
        self._spawn("slurmd", [_exe("slurmd"), "-D", "-N", "localhost", "-f", str(self.conf)])
        self._wait("the node to be idle", lambda: self.run("sinfo", "-h", "-N", "-o", "%t").stdout.strip() == "idle")
        return self

    # -- tear-down ----------------------------------------------------------------------------
    def stop(self) -> None:
        """Cancel any job left, then end the daemons (node, controller, munge) by process id."""
        if "slurmctld" in self.procs and self.procs["slurmctld"].poll() is None:
            try:
                self.run("scancel", "--full", "--partition", self.partition)
            except Exception:  # the daemons are ended below in any case
                pass
        for name in ("slurmd", "slurmctld", "munged"):
            p = self.procs.get(name)
            if p is None or p.poll() is not None:
                continue
            p.terminate()
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(timeout=10)

    def logs(self, tail: int = 40) -> str:
        out = []
        for f in sorted((self.root / "log").glob("*")):
            lines = f.read_text(errors="replace").splitlines()[-tail:]
            out.append(f"--- {f.name}\n" + "\n".join(lines))
        return "\n".join(out)
