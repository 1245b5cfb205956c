"""scripts/validate_deploy.py: the shipped overlays pass, and each rule catches what it is for.

Each test breaks one thing in a freshly rendered overlay (or in the Dockerfile's text) the way a
careless edit would, and asserts the validator names it. Rendering needs kustomize (kubectl >= 1.27
or kustomize v5) and kubernetes-validate: without them these tests fail, they never skip.
"""

import copy
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts"))

import validate_deploy as vd

Manifest = dict[str, Any]
OVERLAYS = {o.name: o for o in vd.OVERLAYS}


@pytest.fixture(scope="module")
def rendered() -> dict[str, list[Manifest]]:
    command = vd.kustomize_command()
    return {name: vd.render(vd.K8S / "overlays" / name, command) for name in OVERLAYS}


@pytest.fixture(scope="module")
def readme() -> str:
    return (vd.DEPLOY / "README.md").read_text()


def find(objects: list[Manifest], kind: str, name: str) -> Manifest:
    return next(o for o in objects if o["kind"] == kind and o["metadata"]["name"] == name)


def container(obj: Manifest) -> Manifest:
    return obj["spec"]["template"]["spec"]["containers"][0]


def findings_after(
    rendered: dict[str, list[Manifest]], readme: str, overlay: str, edit: Callable[[list[Manifest]], None]
) -> list[str]:
    objects = copy.deepcopy(rendered[overlay])
    edit(objects)
    found = vd.overlay_findings(OVERLAYS[overlay], objects, readme)
    return found + vd.schema_findings(objects, vd.KUBERNETES_VERSIONS[0])


def assert_named(findings: list[str], *fragments: str) -> None:
    assert any(all(f in finding for f in fragments) for finding in findings), (
        f"no finding mentions {fragments}: {findings}"
    )


def test_every_shipped_overlay_and_the_dockerfile_pass_every_check() -> None:
    findings, checked = vd.all_findings()
    assert findings == []
    assert [line.split(":")[0] for line in checked] == ["base", *OVERLAYS]


def test_the_unmodified_renders_have_no_findings(rendered: dict[str, list[Manifest]], readme: str) -> None:
    for name in OVERLAYS:
        assert findings_after(rendered, readme, name, lambda _: None) == []


def test_a_worker_grace_period_shorter_than_the_hand_back_is_refused(
    rendered: dict[str, list[Manifest]], readme: str
) -> None:
    def edit(objects: list[Manifest]) -> None:
        find(objects, "Deployment", "vint-worker-render")["spec"]["template"]["spec"][
            "terminationGracePeriodSeconds"
        ] = vd.HAND_BACK_BOUND_S - 1

    assert_named(findings_after(rendered, readme, "production", edit), "vint-worker-render", "hand-back")


def test_a_worker_memory_limit_below_its_engine_bound_plus_headroom_is_refused(
    rendered: dict[str, list[Manifest]], readme: str
) -> None:
    def edit(objects: list[Manifest]) -> None:
        worker = container(find(objects, "Deployment", "vint-worker-render"))
        bound = int(vd.env_value(worker, "VINT_ENGINE_MAX_RSS_MIB", objects) or 0)
        worker["resources"]["limits"]["memory"] = f"{bound + vd.WORKER_HEADROOM_MIB - 1}Mi"
        worker["resources"]["requests"]["memory"] = "1Gi"

    assert_named(findings_after(rendered, readme, "production", edit), "vint-worker-render", "engine bound")


def test_an_engine_worker_without_an_explicit_memory_bound_is_refused(
    rendered: dict[str, list[Manifest]], readme: str
) -> None:
    def edit(objects: list[Manifest]) -> None:
        worker = container(find(objects, "Deployment", "vint-worker-grasp"))
        worker["env"] = [e for e in worker["env"] if e["name"] != "VINT_ENGINE_MAX_RSS_MIB"]

    assert_named(
        findings_after(rendered, readme, "dev", edit), "vint-worker-grasp", "VINT_ENGINE_MAX_RSS_MIB"
    )


def test_a_worker_given_database_credentials_is_refused(
    rendered: dict[str, list[Manifest]], readme: str
) -> None:
    def edit(objects: list[Manifest]) -> None:
        container(find(objects, "Deployment", "vint-worker-noise"))["env"].append(
            {
                "name": "VINT_DATABASE_URL",
                "valueFrom": {"secretKeyRef": {"name": "vint-database", "key": "url"}},
            }
        )

    assert_named(findings_after(rendered, readme, "production", edit), "vint-worker-noise", "database")


def test_envfrom_on_a_worker_is_refused(rendered: dict[str, list[Manifest]], readme: str) -> None:
    def edit(objects: list[Manifest]) -> None:
        container(find(objects, "Deployment", "vint-worker-package"))["envFrom"] = [
            {"secretRef": {"name": "vint-s3"}}
        ]

    assert_named(findings_after(rendered, readme, "production", edit), "vint-worker-package", "envFrom")


@pytest.mark.parametrize(
    ("image", "fragment"),
    [("registry.example.com/vint/vint:latest", ":latest"), ("vint", "neither tag nor digest")],
)
def test_floating_or_unset_images_are_refused(
    rendered: dict[str, list[Manifest]], readme: str, image: str, fragment: str
) -> None:
    def edit(objects: list[Manifest]) -> None:
        container(find(objects, "Deployment", "vint-coordinator"))["image"] = image

    assert_named(findings_after(rendered, readme, "production", edit), "vint-coordinator", fragment)


def test_a_serving_container_without_a_probe_is_refused(
    rendered: dict[str, list[Manifest]], readme: str
) -> None:
    def edit(objects: list[Manifest]) -> None:
        del container(find(objects, "Deployment", "vint-coordinator"))["livenessProbe"]

    assert_named(findings_after(rendered, readme, "dev", edit), "vint-coordinator", "no livenessProbe")


def test_a_writable_root_filesystem_and_kept_capabilities_are_refused(
    rendered: dict[str, list[Manifest]], readme: str
) -> None:
    def edit(objects: list[Manifest]) -> None:
        security = container(find(objects, "StatefulSet", "vint-postgres"))["securityContext"]
        security["readOnlyRootFilesystem"] = False
        security["capabilities"] = {"drop": ["NET_RAW"]}

    found = findings_after(rendered, readme, "dev", edit)
    assert_named(found, "vint-postgres", "readOnlyRootFilesystem")
    assert_named(found, "vint-postgres", "drop ALL")


def test_coordinator_probes_that_ignore_or_overreact_to_the_database_are_refused(
    rendered: dict[str, list[Manifest]], readme: str
) -> None:
    def edit(objects: list[Manifest]) -> None:
        coordinator = container(find(objects, "Deployment", "vint-coordinator"))
        coordinator["readinessProbe"] = {"grpc": {"port": 7700}}
        coordinator["livenessProbe"] = {"grpc": {"port": 7700, "service": "vint.v1.JobService"}}

    found = findings_after(rendered, readme, "dev", edit)
    assert_named(found, "vint-coordinator", "readinessProbe does not follow the database")
    assert_named(found, "vint-coordinator", "livenessProbe follows the database")


def test_a_secret_in_the_production_kustomization_is_refused(
    rendered: dict[str, list[Manifest]], readme: str
) -> None:
    def edit(objects: list[Manifest]) -> None:
        objects.append(
            {"apiVersion": "v1", "kind": "Secret", "metadata": {"name": "vint-s3"}, "stringData": {"a": "b"}}
        )

    assert_named(findings_after(rendered, readme, "production", edit), "overwrite real credentials")
    assert vd.base_findings([{"kind": "Secret", "metadata": {"name": "x"}}]) != []


def test_a_reference_nothing_provides_is_refused(rendered: dict[str, list[Manifest]], readme: str) -> None:
    def edit(objects: list[Manifest]) -> None:
        container(find(objects, "Deployment", "vint-worker-grasp"))["env"].append(
            {"name": "EXTRA", "valueFrom": {"secretKeyRef": {"name": "vint-extra", "key": "k"}}}
        )

    assert_named(findings_after(rendered, readme, "dev", edit), "vint-worker-grasp", "vint-extra")
    assert_named(findings_after(rendered, readme, "production", edit), "vint-worker-grasp", "vint-extra")


def test_an_external_secret_missing_from_the_readme_is_refused(rendered: dict[str, list[Manifest]]) -> None:
    found = vd.overlay_findings(OVERLAYS["production"], rendered["production"], readme="")
    assert_named(found, "vint-worker-token", "not documented")


def test_a_coordinator_that_migrates_or_uses_the_owner_role_is_refused(
    rendered: dict[str, list[Manifest]], readme: str
) -> None:
    def edit(objects: list[Manifest]) -> None:
        coordinator = container(find(objects, "Deployment", "vint-coordinator"))
        coordinator["command"].remove("--no-migrate")
        database = next(e for e in coordinator["env"] if e["name"] == "VINT_DATABASE_URL")
        database["valueFrom"]["secretKeyRef"]["name"] = "vint-database-migrate"

    found = findings_after(rendered, readme, "production", edit)
    assert_named(found, "vint-coordinator", "--no-migrate")
    assert_named(found, "vint-coordinator", "DML rights only")


def test_a_missing_migration_job_is_refused(rendered: dict[str, list[Manifest]], readme: str) -> None:
    def edit(objects: list[Manifest]) -> None:
        objects.remove(find(objects, "Job", "vint-migrate"))

    assert_named(findings_after(rendered, readme, "production", edit), "0 migration Jobs")


def test_one_coordinator_in_production_is_refused(rendered: dict[str, list[Manifest]], readme: str) -> None:
    def edit(objects: list[Manifest]) -> None:
        find(objects, "Deployment", "vint-coordinator")["spec"]["replicas"] = 1

    assert_named(findings_after(rendered, readme, "production", edit), "vint-coordinator", "promises 2")


def test_a_scaled_object_off_schema_is_refused(rendered: dict[str, list[Manifest]], readme: str) -> None:
    def edit(objects: list[Manifest]) -> None:
        scaled = find(objects, "ScaledObject", "vint-worker-render")
        scaled["spec"]["triggers"][0]["metadata"]["threshold"] = 1
        scaled["spec"]["maxReplicas"] = 3

    found = findings_after(rendered, readme, "production", edit)
    assert_named(found, "ScaledObject/vint-worker-render", "threshold", "not of type 'string'")
    assert_named(found, "ScaledObject/vint-worker-render", "maxReplicas")


def test_a_scaled_object_on_another_stages_queue_is_refused(
    rendered: dict[str, list[Manifest]], readme: str
) -> None:
    def edit(objects: list[Manifest]) -> None:
        metadata = find(objects, "ScaledObject", "vint-worker-noise")["spec"]["triggers"][0]["metadata"]
        metadata["query"] = metadata["query"].replace('stage="noise"', 'stage="render"')

    assert_named(findings_after(rendered, readme, "production", edit), "vint-worker-noise", "queue depth")


def test_a_bad_hpa_behavior_is_refused(rendered: dict[str, list[Manifest]], readme: str) -> None:
    def edit(objects: list[Manifest]) -> None:
        scaled = find(objects, "ScaledObject", "vint-worker-grasp")
        scaled["spec"]["advanced"]["horizontalPodAutoscalerConfig"]["behavior"]["scaleDown"]["policies"][0][
            "kind"
        ] = "Pods"

    assert_named(findings_after(rendered, readme, "production", edit), "vint-worker-grasp", "behavior")


def test_replicas_on_an_autoscaled_worker_and_a_worker_without_scaler_are_refused(
    rendered: dict[str, list[Manifest]], readme: str
) -> None:
    def edit(objects: list[Manifest]) -> None:
        find(objects, "Deployment", "vint-worker-grasp")["spec"]["replicas"] = 3
        objects.remove(find(objects, "ScaledObject", "vint-worker-noise"))

    found = findings_after(rendered, readme, "production", edit)
    assert_named(found, "vint-worker-grasp", "ScaledObject owns")
    assert_named(found, "vint-worker-noise", "0 ScaledObjects")


def test_gpus_only_on_render_workers_of_the_gpu_overlay(
    rendered: dict[str, list[Manifest]], readme: str
) -> None:
    def add_gpu(objects: list[Manifest]) -> None:
        container(find(objects, "Deployment", "vint-worker-grasp"))["resources"]["limits"][
            "nvidia.com/gpu"
        ] = "1"

    def drop_toleration(objects: list[Manifest]) -> None:
        del find(objects, "Deployment", "vint-worker-render")["spec"]["template"]["spec"]["tolerations"]

    assert_named(
        findings_after(rendered, readme, "production-gpu", add_gpu), "vint-worker-grasp", "asks for a GPU"
    )
    assert_named(
        findings_after(rendered, readme, "production-gpu", drop_toleration),
        "vint-worker-render",
        "toleration",
    )


def test_tls_on_the_coordinator_needs_https_workers_and_no_grpc_probe(
    rendered: dict[str, list[Manifest]], readme: str
) -> None:
    def edit(objects: list[Manifest]) -> None:
        coordinator = container(find(objects, "Deployment", "vint-coordinator"))
        coordinator["readinessProbe"] = {"grpc": {"port": 7700}}
        find(objects, "ConfigMap", next(o["metadata"]["name"] for o in objects if o["kind"] == "ConfigMap"))[
            "data"
        ]["VINT_COORDINATOR"] = "http://vint-coordinator:7700"

    found = findings_after(rendered, readme, "production", edit)
    assert_named(found, "vint-coordinator", "readinessProbe", "plaintext")
    assert_named(found, "vint-worker-render", "VINT_COORDINATOR", "https://")


def test_an_unknown_kubernetes_field_is_refused(rendered: dict[str, list[Manifest]], readme: str) -> None:
    def edit(objects: list[Manifest]) -> None:
        container(find(objects, "Deployment", "vint-worker-render"))["imagePullPolicyy"] = "Always"

    assert_named(findings_after(rendered, readme, "dev", edit), "vint-worker-render", "imagePullPolicyy")


DOCKERFILE = (vd.DEPLOY / "Dockerfile").read_text()
DOCKERIGNORE = (vd.ROOT / ".dockerignore").read_text()


@pytest.mark.parametrize(
    ("old", "new", "fragment"),
    [
        ("ARG PYTHON_IMAGE=python:3.13.9-slim-bookworm", "ARG PYTHON_IMAGE=python:3.13-slim", "not pinned"),
        ("ARG RUST_IMAGE=rust:1.95.0-bookworm", "ARG RUST_IMAGE=rust:latest", "not pinned"),
        ("cargo build --locked", "cargo build", "--locked"),
        ("--mount=type=cache,target=/usr/local/cargo/registry", "", "cache mount"),
        ("USER 10001:10001", "USER root", "non-root"),
    ],
)
def test_the_dockerfile_rules(old: str, new: str, fragment: str) -> None:
    assert old in DOCKERFILE
    assert vd.dockerfile_findings(DOCKERFILE, DOCKERIGNORE) == []
    assert_named(vd.dockerfile_findings(DOCKERFILE.replace(old, new), DOCKERIGNORE), fragment)


def test_a_dockerignore_that_sends_target_is_refused() -> None:
    ignore = "\n".join(line for line in DOCKERIGNORE.splitlines() if line.strip() != "target")
    assert_named(vd.dockerfile_findings(DOCKERFILE, ignore), "target")


def test_a_dockerignore_that_leaves_out_a_build_input_is_refused() -> None:
    assert_named(vd.dockerfile_findings(DOCKERFILE, DOCKERIGNORE + "\nbenches\n"), "benches", "build reads")


def test_quantities_flags_and_images_parse() -> None:
    assert vd.mebibytes("6Gi") == 6144
    assert vd.mebibytes("1536Mi") == 1536
    assert vd.mebibytes("1G") == pytest.approx(953.674, rel=1e-3)
    with pytest.raises(ValueError, match="not a memory quantity"):
        vd.mebibytes("6 GB")
    worker = {"command": ["vint-worker", "--stages=render", "--scratch", "/scratch", "--log-json"]}
    assert vd.flag(worker, "--stages") == "render"
    assert vd.flag(worker, "--scratch") == "/scratch"
    assert vd.flag(worker, "--log-json") == ""
    assert vd.flag(worker, "--metrics-listen") is None
    assert vd.image_parts("localhost:5000/vint:1.2@sha256:ab") == ("localhost:5000/vint", "1.2", "sha256:ab")
    assert vd.image_parts("localhost:5000/vint") == ("localhost:5000/vint", None, None)


# --- the Prometheus Operator's objects (components/prometheus-operator) --------------------------


def alert(objects: list[Manifest], name: str) -> Manifest:
    rule = find(objects, "PrometheusRule", "vint")
    return next(r for g in rule["spec"]["groups"] for r in g["rules"] if r.get("alert") == name)


def test_the_exported_metrics_are_read_from_the_rust_sources() -> None:
    exported = vd.exported_metrics()
    # A counter is exposed with _total, a histogram as _bucket/_count/_sum, a gauge as registered.
    for name in (
        "vint_tasks_completed_total",
        "vint_tasks_failed_total",
        "vint_queue_tasks",
        "vint_jobs",
        "vint_rpc_duration_seconds_bucket",
        "vint_worker_tasks_total",
        "vint_worker_engine_seconds_count",
    ):
        assert name in exported, name
    for name in (
        "vint_tasks_completed",
        "vint_queue_tasks_total",
        "vint_rpc_duration_seconds",
        "vint_test_events",
    ):
        assert name not in exported, name


def test_a_registration_s_type_comes_from_the_statement_or_the_declarations() -> None:
    source = """
        struct M { hits: Family<Labels, Counter>, depth: Gauge }
        fn new() -> M {
            // registry.register("vint_commented_out", "a comment is no registration", x);
            let mut registry = Registry::default();
            let hits = Family::default();
            registry.register("vint_hits", "Hits; \\"Gauge\\" in help says nothing", Family::clone(&hits));
            let depth = Gauge::default();
            registry.register("vint_depth", "Depth", depth.clone());
            registry.register("vint_build", "Build", prometheus_client::metrics::info::Info::new(labels));
            let seconds = histogram(&mut registry, "vint_seconds", "Time");
            registry.register("vint_mystery", "Unknown", mystery());
            let _ = Command::new("python").args(["-m", "vint_engines"]);
        }
        #[cfg(test)]
        mod tests { fn t() { registry.register("vint_test_only", "x", c.clone()); } }
    """
    assert vd.registered_metrics(source) == {
        "vint_hits": "counter",
        "vint_depth": "gauge",
        "vint_build": "info",
        "vint_seconds": "histogram",
        "vint_mystery": "",
    }


def test_promql_is_read_for_its_series_and_its_brackets() -> None:
    expr = (
        "histogram_quantile(0.99,"
        ' sum by (le, vint_label) (rate(vint_a_bucket{rpc="x",b=~"c|d"}[5m] offset 1h)))'
        " / on (namespace) group_left (pod) max without (instance) (vint_b) > 1e3 and bool up"
        ' unless label_replace(vint_c, "dst", "$1", "vint_not_a_metric", "(.+)")'
    )
    assert vd.promql_metrics(expr) == {"vint_a_bucket", "vint_b", "up", "vint_c"}
    assert vd.promql_findings(expr) == []
    assert_named(vd.promql_findings("sum(rate(vint_a[5m])"), "unclosed")
    assert_named(vd.promql_findings('sum(vint_a{b="c})'), "never closed")
    assert_named(vd.promql_findings("sum(vint_a))"), "unbalanced")
    assert_named(vd.promql_findings("  "), "empty")


@pytest.mark.parametrize(
    ("old", "new"),
    [
        ("vint_tasks_completed_total", "vint_tasks_complete_total"),  # a typo
        ("vint_queue_tasks{", "vint_queue_tasks_total{"),  # a gauge read as a counter
        ("vint_tasks_completed_total", "vint_tasks_completed"),  # a counter without its _total
    ],
)
def test_an_alert_on_a_metric_nothing_exports_is_refused(
    rendered: dict[str, list[Manifest]], readme: str, old: str, new: str
) -> None:
    def edit(objects: list[Manifest]) -> None:
        rule = alert(objects, "VintQueueStalled")
        assert old in rule["expr"]
        rule["expr"] = rule["expr"].replace(old, new)

    name = new.rstrip("{")
    assert_named(
        findings_after(rendered, readme, "production", edit), "VintQueueStalled", name, "no vint process"
    )


def test_an_alert_on_a_job_no_podmonitor_makes_is_refused(
    rendered: dict[str, list[Manifest]], readme: str
) -> None:
    def edit(objects: list[Manifest]) -> None:
        del find(objects, "PodMonitor", "vint-coordinator")["spec"]["jobLabel"]

    found = findings_after(rendered, readme, "production", edit)
    assert_named(found, "VintCoordinatorDown", "job 'vint-coordinator'")


def test_an_alert_without_for_severity_summary_or_runbook_is_refused(
    rendered: dict[str, list[Manifest]], readme: str
) -> None:
    def edit(objects: list[Manifest]) -> None:
        rule = alert(objects, "VintWorkersGone")
        del rule["for"]
        rule["labels"]["severity"] = "page"
        del rule["annotations"]["summary"]
        rule["annotations"]["description"] = "Workers are gone."
        alert(objects, "VintCoordinatorDown")["expr"] = 'absent(up{job="vint-coordinator"} == 1'

    found = findings_after(rendered, readme, "production", edit)
    assert_named(found, "VintWorkersGone", "no `for`")
    assert_named(found, "VintWorkersGone", "severity")
    assert_named(found, "VintWorkersGone", "annotations.summary")
    assert_named(found, "VintWorkersGone", "runbook")
    assert_named(found, "VintCoordinatorDown", "unclosed")


def test_an_alert_missing_from_the_operations_doc_is_refused(
    rendered: dict[str, list[Manifest]], readme: str
) -> None:
    operations = vd.operations_doc().replace("`VintTasksFailedPermanently`", "VintTasksFailedPermanently")
    found = vd.overlay_findings(OVERLAYS["production"], rendered["production"], readme, operations)
    assert_named(found, "VintTasksFailedPermanently", "not documented")
    assert len(found) == 1


def test_podmonitors_on_the_wrong_port_path_or_scheme_are_refused(
    rendered: dict[str, list[Manifest]], readme: str
) -> None:
    def edit(objects: list[Manifest]) -> None:
        coordinator = find(objects, "PodMonitor", "vint-coordinator")["spec"]["podMetricsEndpoints"][0]
        coordinator["scheme"] = "http"
        worker = find(objects, "PodMonitor", "vint-worker")["spec"]["podMetricsEndpoints"][0]
        worker["port"] = "http"
        worker["path"] = "/healthz"

    found = findings_after(rendered, readme, "production", edit)
    assert_named(found, "PodMonitor/vint-coordinator", "Deployment/vint-coordinator", "HTTPS")
    assert_named(
        found, "PodMonitor/vint-worker", "Deployment/vint-worker-render", "--metrics-listen port 9090"
    )
    assert_named(found, "PodMonitor/vint-worker", "/healthz")


def test_an_https_scrape_that_cannot_verify_the_coordinator_is_refused(
    rendered: dict[str, list[Manifest]], readme: str
) -> None:
    def edit(objects: list[Manifest]) -> None:
        endpoint = find(objects, "PodMonitor", "vint-coordinator")["spec"]["podMetricsEndpoints"][0]
        endpoint["tlsConfig"] = {"insecureSkipVerify": True}

    assert_named(findings_after(rendered, readme, "production", edit), "vint-coordinator", "tlsConfig.ca")


def test_a_worker_no_podmonitor_scrapes_is_refused(rendered: dict[str, list[Manifest]], readme: str) -> None:
    def edit(objects: list[Manifest]) -> None:
        find(objects, "PodMonitor", "vint-worker")["spec"]["selector"]["matchLabels"]["vint/stage"] = "render"

    found = findings_after(rendered, readme, "production", edit)
    assert_named(found, "Deployment/vint-worker-grasp", "0 PodMonitors")
    assert not any("vint-worker-render" in f and "PodMonitors select" in f for f in found)


def test_a_metric_relabeling_that_names_a_missing_metric_is_refused(
    rendered: dict[str, list[Manifest]], readme: str
) -> None:
    def edit(objects: list[Manifest]) -> None:
        endpoint = find(objects, "PodMonitor", "vint-worker")["spec"]["podMetricsEndpoints"][0]
        endpoint["metricRelabelings"] = [
            {
                "sourceLabels": ["__name__"],
                "regex": "(vint_worker_fetch_seconds_bucket|vint_worker_fetch_second_bucket)",
                "action": "drop",
            }
        ]

    found = findings_after(rendered, readme, "production", edit)
    assert_named(found, "PodMonitor/vint-worker", "vint_worker_fetch_second_bucket")
    assert not any("vint_worker_fetch_seconds_bucket" in f for f in found)


def test_monitoring_objects_off_schema_are_refused(rendered: dict[str, list[Manifest]], readme: str) -> None:
    def edit(objects: list[Manifest]) -> None:
        find(objects, "PodMonitor", "vint-worker")["spec"]["podMetricsEndpoints"][0]["targetport"] = 9090
        alert(objects, "VintQueueStalled")["for"] = "15 minutes"

    found = findings_after(rendered, readme, "production", edit)
    assert_named(found, "PodMonitor/vint-worker", "PodMonitor schema", "targetport")
    assert_named(found, "PrometheusRule/vint", "PrometheusRule schema", "15 minutes")


def test_monitoring_objects_where_no_operator_is_promised_are_refused(
    rendered: dict[str, list[Manifest]], readme: str
) -> None:
    def edit(objects: list[Manifest]) -> None:
        objects.append(copy.deepcopy(find(rendered["production"], "PodMonitor", "vint-worker")))

    assert_named(
        findings_after(rendered, readme, "dev", edit), "PodMonitor/vint-worker", "no Prometheus Operator"
    )


def test_the_docs_quote_the_shipped_keda_query(rendered: dict[str, list[Manifest]], readme: str) -> None:
    objects = copy.deepcopy(rendered["production"])
    operations = vd.operations_doc()
    assert vd.docs_findings(objects, readme, operations) == []
    trigger = find(objects, "ScaledObject", "vint-worker-render")["spec"]["triggers"][0]["metadata"]
    trigger["query"] = 'max(vint_queue_tasks{stage="render",state="queued"})'
    found = vd.docs_findings(objects, readme, operations)
    assert_named(found, "deploy/README.md", "vint-worker-render")
    assert_named(found, "docs/operations.md", "vint-worker-render")
