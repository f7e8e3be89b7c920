"""A one-node Slurm cluster on localhost, for trying ``python -m abcgs.cluster`` on one machine, for the tests
(``tests/test_cluster.py``) and for the benchmark (``eval/bench/cluster.py``). It administers this host, which is why
it is not part of the installed ``abcgs`` package::

    sudo python -m eval.slurm_local install          # Debian's slurm-wlm and munge (apt-get; root)
    sudo python -m eval.slurm_local start /tmp/slurm # munged, slurmctld, slurmd; prints the SLURM_CONF to export
    SLURM_CONF=/tmp/slurm/slurm.conf python -m abcgs.cluster submit --cluster-dir /tmp/abcgs-cluster
    sudo python -m eval.slurm_local stop /tmp/slurm  # cancels every job, stops the daemons

:class:`LocalSlurm` starts ``munged`` with a generated key, then ``slurmctld`` and ``slurmd`` with a generated
``slurm.conf`` (one node ``localhost`` with this machine's cores, ``select/cons_tres``, ``proctrack/linuxproc``,
``task/none``, no accounting storage, every state folder and socket under ``root``, free ports), and stops them on
:meth:`LocalSlurm.stop`. Client commands find the cluster through ``SLURM_CONF`` (:attr:`LocalSlurm.env`).
``slurmd`` starts the jobs as their users, so it runs as root.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

from abcgs.errors import AbcgsError

DAEMONS = ("munged", "slurmctld", "slurmd", "sbatch", "squeue", "scontrol", "scancel", "sinfo")

CONF_TEMPLATE = """\
ClusterName=abcgslocal
SlurmctldHost=localhost
SlurmctldPort={ctld_port}
SlurmdPort={slurmd_port}
SlurmUser={user}
SlurmdUser=root
AuthType=auth/munge
AuthInfo=socket={root}/munge/munge.socket,cred_expire=5
CredType=cred/munge
StateSaveLocation={root}/state
SlurmdSpoolDir={root}/spool
SlurmctldPidFile={root}/slurmctld.pid
SlurmdPidFile={root}/slurmd.pid
SlurmctldLogFile={root}/log/slurmctld.log
SlurmdLogFile={root}/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
SchedulerType=sched/backfill
SchedulerParameters=sched_interval=1,bf_interval=1
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
MpiDefault=none
ReturnToService=2
MinJobAge=3600
MailProg=/bin/true
PlugStackConfig=/dev/null
NodeName=localhost CPUs={cpus} RealMemory={memory_mb} State=UNKNOWN
PartitionName=local Nodes=localhost Default=YES MaxTime=INFINITE State=UP
"""
"""``cred_expire=5``: a requeued job waits 5 s, not Slurm's default 121 s, before it may start again."""


class SlurmUnavailable(AbcgsError):
    """Slurm or munge is not installed here and cannot be installed (the message says why)."""


def missing_commands() -> list[str]:
    return [c for c in DAEMONS if shutil.which(c) is None]


def install() -> None:
    """Install Debian's ``slurm-wlm`` and ``munge`` when a command is missing (needs root and apt-get)."""
    if not missing_commands():
        return
    if os.geteuid() != 0:
        raise SlurmUnavailable(f"{', '.join(missing_commands())} missing and not root: "
                               "apt-get install slurm-wlm munge as root first")
    if shutil.which("apt-get") is None:
        raise SlurmUnavailable(f"{', '.join(missing_commands())} missing and no apt-get: install Slurm and munge")
    env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    for cmd in (["apt-get", "update", "-q"], ["apt-get", "install", "-y", "-q", "slurm-wlm", "munge"]):
        proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
        if proc.returncode != 0:
            raise SlurmUnavailable(f"{' '.join(cmd)} failed: {proc.stderr.strip()[-1000:]}")
    if missing_commands():
        raise SlurmUnavailable(f"still missing after apt-get install: {', '.join(missing_commands())}")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _memory_mb() -> int:
    """80 % of this machine's memory, in MB (the node's RealMemory)."""
    for line in Path("/proc/meminfo").read_text().splitlines():
        if line.startswith("MemTotal:"):
            return int(int(line.split()[1]) / 1024 * 0.8)
    return 4096


class LocalSlurm:
    """A one-node Slurm cluster under ``root`` (module docstring); a context manager."""

    def __init__(self, root: Path, cpus: int | None = None) -> None:
        self.root = Path(root).resolve()
        self.cpus = cpus or os.cpu_count() or 1
        self.conf = self.root / "slurm.conf"
        self.env = {**os.environ, "SLURM_CONF": str(self.conf)}

    def _run(self, cmd: list[str], check: bool = True) -> subprocess.CompletedProcess:
        proc = subprocess.run(cmd, env=self.env, capture_output=True, text=True, timeout=60)
        if check and proc.returncode != 0:
            raise SlurmUnavailable(f"{' '.join(cmd)} failed ({proc.returncode}): {proc.stderr.strip()}\n{self.logs()}")
        return proc

    def logs(self, lines: int = 20) -> str:
        out = []
        for name in ("munge/munged.log", "log/slurmctld.log", "log/slurmd.log"):
            path = self.root / name
            if path.is_file():
                out.append(f"--- {name}\n" + "\n".join(path.read_text(errors="replace").splitlines()[-lines:]))
        return "\n".join(out)

    def start(self, timeout: float = 60.0) -> LocalSlurm:
        """Start munged, slurmctld and slurmd; return once the node is idle."""
        for d in ("munge", "state", "spool", "log"):
            (self.root / d).mkdir(parents=True, exist_ok=True)
        munge = self.root / "munge"
        munge.chmod(0o755)  # munged wants its socket folder reachable by every client
        key = munge / "munge.key"
        key.write_bytes(os.urandom(1024))
        key.chmod(0o400)
        self._run(["munged", "--force", f"--key-file={key}", f"--socket={munge / 'munge.socket'}",
                   f"--pid-file={munge / 'munged.pid'}", f"--log-file={munge / 'munged.log'}",
                   f"--seed-file={munge / 'munged.seed'}"])
        self.conf.write_text(CONF_TEMPLATE.format(
            root=self.root, ctld_port=_free_port(), slurmd_port=_free_port(), cpus=self.cpus,
            memory_mb=_memory_mb(), user=os.environ.get("USER") or "root"))
        self._run(["slurmctld"])
        self._run(["slurmd", "-N", "localhost"])
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            state = self._run(["sinfo", "-h", "-o", "%T"], check=False).stdout.strip()
            if state == "idle":
                return self
            time.sleep(0.5)
        raise SlurmUnavailable(f"the node did not come up (sinfo: {state!r})\n{self.logs()}")

    def _pid(self, name: str) -> int | None:
        path = self.root / name
        try:
            return int(path.read_text().split()[0])
        except (OSError, ValueError, IndexError):
            return None

    def stop(self, timeout: float = 30.0) -> None:
        """Cancel every job, wait for them to end, then stop slurmd, slurmctld and munged (by their pids)."""
        if self.conf.is_file():
            self._run(["scancel", "--full", "--user", os.environ.get("USER") or "root"], check=False)
            deadline = time.monotonic() + timeout
            while time.monotonic() < deadline and self._run(["squeue", "-h"], check=False).stdout.strip():
                time.sleep(0.5)
        for pid in (self._pid("slurmd.pid"), self._pid("slurmctld.pid"), self._pid("munge/munged.pid")):
            if pid is None:
                continue
            try:
                os.kill(pid, signal.SIGTERM)
            except ProcessLookupError:
                continue
            for _ in range(100):
                try:
                    os.kill(pid, 0)
                except ProcessLookupError:
                    break
                time.sleep(0.1)

    def __enter__(self) -> LocalSlurm:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m eval.slurm_local", description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    sub.add_parser("install", help="apt-get install slurm-wlm munge where a command is missing (root)")
    for name, text in (("start", "start a one-node cluster with its state under ROOT"),
                       ("stop", "cancel its jobs and stop the cluster started under ROOT")):
        c = sub.add_parser(name, help=text)
        c.add_argument("root", type=Path)
        if name == "start":
            c.add_argument("--cpus", type=int, help="the node's cores (default: this machine's)")
    a = ap.parse_args(argv)
    try:
        if a.cmd == "install":
            install()
            print("slurm-wlm and munge are installed")
        elif a.cmd == "start":
            if missing_commands():
                raise SlurmUnavailable(f"{', '.join(missing_commands())} missing: "
                                       "run `sudo python -m eval.slurm_local install` first")
            cluster = LocalSlurm(a.root, a.cpus).start()
            print(f"export SLURM_CONF={cluster.conf}")
        else:
            LocalSlurm(a.root).stop()
    except SlurmUnavailable as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
