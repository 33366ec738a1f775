"""deploy/: compose and Kubernetes files parse and hold what the cluster needs (Docker cannot
run here, so this is the check we can make)."""

from __future__ import annotations

from pathlib import Path

import yaml

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
