"""deploy/: compose and Kubernetes files parse and hold what the cluster needs (Docker cannot
run here, so this is the check we can make)."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import yaml

from service.settings import ServiceSettings

DEPLOY = Path(__file__).parents[1] / "deploy"


def test_compose_services_wait_for_healthy_dependencies() -> None:
    compose = yaml.safe_load((DEPLOY / "compose.yaml").read_text())
    services = compose["services"]
    assert set(services) == {"postgres", "rabbitmq", "api", "worker", "gpu-worker"}
    for name, svc in services.items():
        assert "healthcheck" in svc or name in ("worker", "gpu-worker"), name
        for dep in svc.get("depends_on", {}).values():
            assert dep == {"condition": "service_healthy"}
    gpu = services["gpu-worker"]["deploy"]["resources"]["reservations"]["devices"][0]
    assert gpu["driver"] == "nvidia" and "gpu" in gpu["capabilities"]
    for name in ("api", "worker", "gpu-worker"):
        env = services[name]["environment"]
        assert {"FOREST_DATABASE_URL", "FOREST_BROKER_URL", "FOREST_ARTIFACTS_DIR"} <= set(env)
        assert (DEPLOY.parent / services[name]["build"]["dockerfile"]).is_file()


def _consumed(services: dict[str, Any], profile: str | None) -> set[str]:
    """The queues the workers `docker compose [--profile P] up` starts consume."""
    queues: set[str] = set()
    for svc in services.values():
        command = svc.get("command") or []
        if "worker" in command and set(svc.get("profiles", [])) <= {profile}:
            queues |= set(command[command.index("-Q") + 1].split(","))
    return queues


def test_compose_renders_without_a_gpu_and_with_one() -> None:
    """Plain `docker compose up` (no GPU on the host) consumes every queue a job without a
    pool goes to, renders included (CPU workers, llvmpipe); the GPU worker comes only with
    the `gpu` profile and takes the `gpu` pool's renders and any pool's."""
    from farm.dispatch import KIND_QUEUES, QUEUES

    services = yaml.safe_load((DEPLOY / "compose.yaml").read_text())["services"]
    assert services["gpu-worker"]["profiles"] == ["gpu"]
    assert set(KIND_QUEUES.values()) | {"cpu"} <= _consumed(services, None)
    assert _consumed(services, "gpu") == set(QUEUES)
    assert "libegl-mesa0" in (DEPLOY / "worker.Dockerfile").read_text()


class _ComposeLoader(yaml.SafeLoader):
    """YAML with Compose's merge tags: ``!override`` marks a value that replaces, not merges."""


class _Override(dict):  # type: ignore[type-arg]
    pass


_ComposeLoader.add_constructor(
    "!override", lambda loader, node: _Override(loader.construct_mapping(node, deep=True))
)


def _merge(base: object, over: object) -> object:
    """Compose's merge rules for the mappings these files use: keys merge recursively unless
    the override says ``!override``."""
    if isinstance(over, _Override) or not (isinstance(base, dict) and isinstance(over, dict)):
        return dict(over) if isinstance(over, _Override) else over
    return {k: _merge(base[k], v) if k in base else v for k, v in over.items()} | {
        k: v for k, v in base.items() if k not in over
    }


def test_compose_redis_variant_replaces_rabbitmq() -> None:
    base = yaml.safe_load((DEPLOY / "compose.yaml").read_text())
    over = yaml.load((DEPLOY / "compose.redis.yaml").read_text(), _ComposeLoader)
    merged = _merge(base, over)
    assert isinstance(merged, dict)
    services = merged["services"]
    assert services["rabbitmq"]["profiles"] == ["rabbitmq"]  # not started by default
    assert "healthcheck" in services["redis"]
    for name in ("api", "worker", "gpu-worker"):
        svc = services[name]
        assert "rabbitmq" not in svc["depends_on"] and "redis" in svc["depends_on"], name
        for dep in svc["depends_on"].values():
            assert dep == {"condition": "service_healthy"}
        env = {k: str(v) for k, v in svc["environment"].items()}
        settings = ServiceSettings(**{k.removeprefix("FOREST_").lower(): v for k, v in env.items()})
        assert settings.is_redis, name
        assert settings.database_url == env["FOREST_DATABASE_URL"]  # the base's, kept
    assert "redis" in merged["volumes"]


def test_kubernetes_manifests() -> None:
    docs = [
        d
        for f in sorted((DEPLOY / "k8s").glob("*.yaml"))
        for d in yaml.safe_load_all(f.read_text())
        if d and "metadata" in d
    ]
    kinds = {(d["kind"], d["metadata"]["name"]) for d in docs}
    assert {
        ("Deployment", "forest-api"),
        ("Service", "forest-api"),
        ("Deployment", "forest-worker"),
        ("Deployment", "forest-gpu-worker"),
        ("ScaledObject", "forest-worker"),
        ("ScaledObject", "forest-gpu-worker"),
    } <= kinds
    gpu = next(
        d
        for d in docs
        if d["metadata"].get("name") == "forest-gpu-worker" and d["kind"] == "Deployment"
    )
    limits = gpu["spec"]["template"]["spec"]["containers"][0]["resources"]["limits"]
    assert limits["nvidia.com/gpu"] == 1
    scaled = [d for d in docs if d["kind"] == "ScaledObject"]
    queues = {
        d["metadata"]["name"]: [t["metadata"]["queueName"] for t in d["spec"]["triggers"]]
        for d in scaled
    }
    assert queues == {"forest-worker": ["default"], "forest-gpu-worker": ["gpu", "render"]}


def _pod_specs() -> list[tuple[str, dict[str, Any]]]:
    """(name, pod spec) of every workload in deploy/k8s (Deployments, StatefulSets, Jobs...)."""
    specs = []
    for f in sorted((DEPLOY / "k8s").glob("*.yaml")):
        for d in yaml.safe_load_all(f.read_text()):
            template = (d or {}).get("spec", {}).get("template") if isinstance(d, dict) else None
            if template is not None:
                specs.append((d["metadata"]["name"], template["spec"]))
    return specs


def test_kubernetes_pods_are_locked_down() -> None:
    specs = _pod_specs()
    assert {name for name, _ in specs} >= {"forest-api", "forest-worker", "forest-gpu-worker"}
    for name, spec in specs:
        pod = spec.get("securityContext", {})
        assert pod.get("runAsNonRoot") is True and pod.get("runAsUser", 0) > 0, name
        assert pod.get("seccompProfile") == {"type": "RuntimeDefault"}, name
        mounts = {v["name"] for v in spec.get("volumes", [])}
        for c in spec["containers"] + spec.get("initContainers", []):
            sc = c.get("securityContext", {})
            where = f"{name}/{c['name']}"
            assert sc.get("allowPrivilegeEscalation") is False, where
            assert sc.get("readOnlyRootFilesystem") is True, where
            assert sc.get("capabilities", {}).get("drop") == ["ALL"], where
            assert not sc.get("capabilities", {}).get("add"), where
            assert not sc.get("privileged"), where
            # a read-only root needs a writable /tmp (tempfile, multiprocessing)
            tmp = [m for m in c.get("volumeMounts", []) if m["mountPath"] == "/tmp"]
            assert tmp and tmp[0]["name"] in mounts, where


def _defaulted_secrets(text: str) -> list[str]:
    """Secrets in a compose file that Compose would start without: a password, key or
    credential URL not written as ``${VAR:?message}``."""
    found = []
    for var, rest in re.findall(r"\$\{(\w+)([^}]*)\}", text):
        if re.search(r"PASSWORD|PASS$|SECRET|KEYS?$", var) and not rest.startswith(":?"):
            found.append(var)
    compose = yaml.load(text, _ComposeLoader)
    for name, svc in compose.get("services", {}).items():
        env = svc.get("environment") or {}
        for key, value in env.items() if isinstance(env, dict) else ():
            secrets = re.findall(r"//\w+:([^@]+)@", str(value))  # a password in a URL
            if re.search(r"PASSWORD|PASS$", key):
                secrets.append(str(value))
            found += [f"{name}.{key}" for v in secrets if not re.fullmatch(r"\$\{\w+:\?[^}]*\}", v)]
    return found


def test_compose_has_no_default_passwords() -> None:
    """Every secret comes from the environment (or .env) and Compose refuses to start without
    it (``${VAR:?message}``): no password has a default such as ``forest``."""
    for f in sorted(DEPLOY.glob("compose*.yaml")):
        assert _defaulted_secrets(f.read_text()) == [], f.name
    base = (DEPLOY / "compose.yaml").read_text()
    for weak in (":-forest}", "}"):  # the check sees a default, and a variable left optional
        mutated = base.replace(":?set POSTGRES_PASSWORD}", weak)
        assert "POSTGRES_PASSWORD" in _defaulted_secrets(mutated)
    assert _defaulted_secrets(base.replace("${RABBITMQ_PASSWORD:?set RABBITMQ_PASSWORD}", "forest"))
