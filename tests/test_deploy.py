"""deploy/: compose and Kubernetes files parse and hold what the cluster needs (Docker cannot
run here, so this is the check we can make)."""

from __future__ import annotations

from pathlib import Path

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
    gpu = next(d for d in docs if d["metadata"].get("name") == "forest-gpu-worker"
               and d["kind"] == "Deployment")
    limits = gpu["spec"]["template"]["spec"]["containers"][0]["resources"]["limits"]
    assert limits["nvidia.com/gpu"] == 1
    scaled = [d for d in docs if d["kind"] == "ScaledObject"]
    assert {d["spec"]["triggers"][0]["metadata"]["queueName"] for d in scaled} == {"default", "gpu"}
