"""The task runner a flow fans out on: threads in the flow process (default), processes, or a Ray cluster.

`WORLDLINE_TASK_RUNNER=process` runs tasks in a pool of `WORLDLINE_WORKERS` spawned processes
(Prefect's ProcessPoolTaskRunner): no GIL shared between the workers, at the price of a few
seconds to start each one.

`WORLDLINE_TASK_RUNNER=ray` runs tasks through prefect-ray (the `ray` extra) on the cluster at
`WORLDLINE_RAY_ADDRESS`, or on a local cluster started for the flow run when none is given.
Either way tasks only return records: the flow process stays the one lineage writer.
"""

from __future__ import annotations

import os

from prefect.task_runners import ProcessPoolTaskRunner, TaskRunner, ThreadPoolTaskRunner

from schemas.settings import Settings

# Ray workers are fresh processes: they see Worldline's settings and the flow's Prefect API
# (its URL and auth string) only through the environment the runner hands them. Server-side
# settings stay behind: the workers are clients, and a cluster shows each job's runtime env to
# anyone who reaches its dashboard (a database URL holds a password).
_FORWARDED_PREFIXES = ("WORLDLINE_", "PREFECT_", "MUJOCO_GL")
_SERVER_ONLY_PREFIXES = ("PREFECT_SERVER_", "PREFECT_API_DATABASE_")


def ray_worker_env(environ: dict[str, str] | None = None) -> dict[str, str]:
    """The variables of `environ` (this process's by default) a Ray worker gets."""
    environ = os.environ if environ is None else environ
    return {k: v for k, v in environ.items()
            if k.startswith(_FORWARDED_PREFIXES) and not k.startswith(_SERVER_ONLY_PREFIXES)}


def task_runner(settings: Settings | None = None) -> TaskRunner:
    settings = settings or Settings()
    if settings.task_runner == "local":
        return ThreadPoolTaskRunner(max_workers=settings.workers)
    if settings.task_runner == "process":
        return ProcessPoolTaskRunner(max_workers=settings.workers)
    try:
        from prefect_ray import RayTaskRunner
    except ImportError as exc:
        raise RuntimeError("WORLDLINE_TASK_RUNNER=ray needs the ray extra: pip install -e '.[ray]'") from exc

    class WorkerEnvRayTaskRunner(RayTaskRunner):
        """RayTaskRunner whose workers report to this flow's Prefect API.

        Without PREFECT_API_URL each Ray worker would start an ephemeral Prefect server of its
        own (about 20 s per worker here) and the task runs would not show in the flow's API.
        """

        def __enter__(self):
            from prefect.context import SyncClientContext

            env = ray_worker_env()
            ctx = SyncClientContext.get()
            if ctx is not None:
                env["PREFECT_API_URL"] = str(ctx.client.api_url).rstrip("/")
            runtime_env = dict(self.init_kwargs.get("runtime_env") or {})
            runtime_env["env_vars"] = {**env, **runtime_env.get("env_vars", {})}
            self.init_kwargs["runtime_env"] = runtime_env
            return super().__enter__()

        def duplicate(self):
            return type(self)(address=self.address, init_kwargs=self.init_kwargs)

    # A local cluster lives as long as one flow run: no dashboard (its job API runs code).
    init_kwargs: dict = {"include_dashboard": False} if not settings.ray_address else {}
    if not settings.ray_address:
        init_kwargs["num_cpus"] = settings.workers
    return WorkerEnvRayTaskRunner(address=settings.ray_address, init_kwargs=init_kwargs)
