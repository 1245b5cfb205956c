#!/usr/bin/env python3
"""Renders deploy/'s kustomize overlays and checks what they mean, not only their syntax.

    scripts/validate_deploy.py      exit 0 when every overlay passes; else 1, listing every finding

Rendering is real kustomize: a `kustomize` v5 binary on PATH, else `kubectl kustomize` (kubectl 1.27
and later embed kustomize v5). Neither is a Python package; without one this fails and says so.

Every rendered object is validated strictly (an unknown field is an error) against the Kubernetes
API's OpenAPI schemas of each version in KUBERNETES_VERSIONS, offline, by `kubernetes-validate`
(pinned in workers/engines/requirements-dev.lock). KEDA's ScaledObject is a custom resource those
schemas lack, and no package carries KEDA's CRD schema offline: it is checked against
SCALED_OBJECT_SCHEMA below, a strict JSON Schema of the ScaledObject fields and prometheus-trigger
parameters KEDA 2.x documents — written here from KEDA's documentation, not KEDA's own CRD schema —
and its HPA `behavior` against the Kubernetes autoscaling/v2 schema. The Prometheus Operator's
PodMonitor and PrometheusRule (components/prometheus-operator) are custom resources too: they are
checked against PODMONITOR_SCHEMA and PROMETHEUS_RULE_SCHEMA, strict JSON Schemas of the fields
that matter here, a subset written from the operator's monitoring.coreos.com/v1 CRDs.

Then the rules a platform engineer would hold the manifests to (`overlay_findings`): resources that
fit the engines' memory bound, probes, locked-down security contexts, no Secret in base or production,
no floating image tags, worker grace periods that cover the lease hand-back, no database credentials
in workers, one migration Job and replicas that never migrate, autoscaling per stage on queue depth,
GPU render nodes only where asked for, PodMonitors that scrape the port and scheme each pod serves,
alerts whose every metric is one the Rust code registers (`exported_metrics`: a misspelt name is a
finding) and whose every alert has `for`, a severity, a summary and a runbook in docs/operations.md,
which must also quote the query the ScaledObjects scale on. `dockerfile_findings` checks
deploy/Dockerfile's structure (no container runtime here builds it).
"""

import json
import re
import shutil
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import jsonschema
import kubernetes_validate
import yaml

ROOT = Path(__file__).resolve().parent.parent
DEPLOY = ROOT / "deploy"
K8S = DEPLOY / "k8s"

# The oldest Kubernetes these manifests support (gRPC probes, autoscaling/v2, policy/v1 are GA well
# before it) and the newest schema kubernetes-validate ships.
KUBERNETES_VERSIONS = ("1.30.0", "1.37.0")

# The pipeline's stages, as the generated contract schema lists them (a new stage needs its worker
# Deployment and autoscaler here, and no edit of this script).
ENGINES = ROOT / "workers" / "engines" / "vint_engines"
STAGES = tuple(sorted(json.loads((ENGINES / "contract.schema.json").read_text(encoding="utf-8"))["stages"]))
# Stages whose worker runs a Python engine that VINT_ENGINE_MAX_RSS_MIB bounds (package is Rust).
ENGINE_STAGES = tuple(s for s in STAGES if (ENGINES / s / "engine.py").is_file())
# Memory a worker pod needs above its engine's bound: the Rust worker itself, and one task's growth
# past the bound (the worker checks the engine's RSS between tasks).
WORKER_HEADROOM_MIB = 1024
# A worker given SIGTERM kills its engine and hands its leases back within seconds; its grace period
# must cover that with margin, never a whole task (up to --task-timeout-s, 1800 s).
HAND_BACK_BOUND_S = 30
# The coordinator drains in-flight RPCs for up to 30 s on SIGTERM.
COORDINATOR_DRAIN_S = 30
# gRPC health names SERVING only while the database answers ("" is the process alone).
API_SERVICES = ("vint.v1.WorkService", "vint.v1.JobService")

# Created out of band in production (deploy/README.md, "First deploy"): the overlay refers to them
# by name and must never contain them.
EXTERNAL_SECRETS = frozenset(
    {
        "vint-database",
        "vint-database-migrate",
        "vint-s3",
        "vint-auth-tokens",
        "vint-worker-token",
        "vint-coordinator-tls",
    }
)
EXTERNAL_CONFIGMAPS = frozenset({"vint-coordinator-ca", "vint-postgres-ca"})

# What the image build reads from its context: the workspace (every member's manifest and targets,
# tests/ and the bench it names in benches/ included), the files crates compile in, the engines.
BUILD_INPUTS = frozenset(
    {
        "Cargo.toml",
        "Cargo.lock",
        "services",
        "workers",
        "tests",
        "benches",
        "proto",
        "migrations",
        "catalog",
        "examples",
    }
)

# Where vint's processes register their metrics (prometheus-client's `Registry::register`): the
# telemetry crate (vint_build_info), the coordinator and the worker.
METRIC_SOURCES = (
    ROOT / "services" / "telemetry" / "src",
    ROOT / "services" / "coordinator" / "src",
    ROOT / "workers" / "runtime" / "src",
)
# The series an alert may read besides vint's own, and who writes them.
EXTERNAL_METRICS = {
    "up": "Prometheus, one series per scrape target",
}
# What the alerts' runbooks are: docs/operations.md, section "Alerts".
OPERATIONS_DOC = ROOT / "docs" / "operations.md"
ALERTS_SECTION = "Alerts"
ALERT_SEVERITIES = frozenset({"critical", "warning", "info"})

Manifest = dict[str, Any]


@dataclass(frozen=True)
class Overlay:
    """An overlay and what it promises."""

    name: str
    # Secrets come from outside the kustomization (production) rather than a generator (dev).
    external_secrets: bool
    min_coordinators: int
    autoscaled: bool
    gpu_render: bool
    # PodMonitors and alerts for the Prometheus Operator (components/prometheus-operator).
    monitored: bool


OVERLAYS = (
    Overlay(
        "dev", external_secrets=False, min_coordinators=1, autoscaled=False, gpu_render=False, monitored=False
    ),
    Overlay(
        "production",
        external_secrets=True,
        min_coordinators=2,
        autoscaled=True,
        gpu_render=False,
        monitored=True,
    ),
    Overlay(
        "production-gpu",
        external_secrets=True,
        min_coordinators=2,
        autoscaled=True,
        gpu_render=True,
        monitored=True,
    ),
)

_STRING = {"type": "string"}
_INT = {"type": "integer"}
_BOOLEAN = {"type": "boolean"}
_STRING_MAP = {"type": "object", "additionalProperties": _STRING}
_METADATA = {
    "type": "object",
    "additionalProperties": False,
    "required": ["name"],
    "properties": {
        "name": _STRING,
        "namespace": _STRING,
        "labels": _STRING_MAP,
        "annotations": _STRING_MAP,
    },
}
# ScaledObject (keda.sh/v1alpha1) as KEDA 2.x documents it: https://keda.sh/docs/latest/reference/scaledobject-spec/
SCALED_OBJECT_SCHEMA: dict[str, Any] = {
    "type": "object",
    "additionalProperties": False,
    "required": ["apiVersion", "kind", "metadata", "spec"],
    "properties": {
        "apiVersion": {"const": "keda.sh/v1alpha1"},
        "kind": {"const": "ScaledObject"},
        "metadata": _METADATA,
        "spec": {
            "type": "object",
            "additionalProperties": False,
            "required": ["scaleTargetRef", "triggers"],
            "properties": {
                "scaleTargetRef": {
                    "type": "object",
                    "additionalProperties": False,
                    "required": ["name"],
                    "properties": {
                        "name": _STRING,
                        "kind": _STRING,
                        "apiVersion": _STRING,
                        "envSourceContainerName": _STRING,
                    },
                },
                "pollingInterval": {"type": "integer", "minimum": 1},
                "cooldownPeriod": {"type": "integer", "minimum": 0},
                "initialCooldownPeriod": {"type": "integer", "minimum": 0},
                "idleReplicaCount": {"type": "integer", "minimum": 0},
                "minReplicaCount": {"type": "integer", "minimum": 0},
                "maxReplicaCount": {"type": "integer", "minimum": 1},
                "fallback": {
                    "type": "object",
                    "additionalProperties": False,
                    "required": ["failureThreshold", "replicas"],
                    "properties": {"failureThreshold": _INT, "replicas": _INT},
                },
                "advanced": {
                    "type": "object",
                    "additionalProperties": False,
                    "properties": {
                        "restoreToOriginalReplicaCount": {"type": "boolean"},
                        "horizontalPodAutoscalerConfig": {
                            "type": "object",
                            "additionalProperties": False,
                            "properties": {"name": _STRING, "behavior": {"type": "object"}},
                        },
                    },
                },
                "triggers": {
                    "type": "array",
                    "minItems": 1,
                    "items": {
                        "type": "object",
                        "additionalProperties": False,
                        "required": ["type", "metadata"],
                        "properties": {
                            "type": _STRING,
                            "name": _STRING,
                            "metricType": {"enum": ["AverageValue", "Value", "Utilization"]},
                            "useCachedMetrics": {"type": "boolean"},
                            # KEDA's trigger metadata is map[string]string: a YAML number or boolean
                            # there is refused by the API server.
                            "metadata": {"type": "object", "additionalProperties": _STRING},
                            "authenticationRef": {
                                "type": "object",
                                "additionalProperties": False,
                                "required": ["name"],
                                "properties": {"name": _STRING, "kind": _STRING},
                            },
                        },
                    },
                },
            },
        },
    },
}
# The prometheus scaler's parameters: https://keda.sh/docs/latest/scalers/prometheus/
PROMETHEUS_TRIGGER_REQUIRED = frozenset({"serverAddress", "query", "threshold"})
PROMETHEUS_TRIGGER_KEYS = PROMETHEUS_TRIGGER_REQUIRED | {
    "activationThreshold",
    "namespace",
    "customHeaders",
    "ignoreNullValues",
    "queryParameters",
    "unsafeSsl",
    "timeout",
    "authModes",
}

# The Prometheus Operator's monitoring.coreos.com/v1 PodMonitor and PrometheusRule: the fields a vint
# overlay may use, with the types, enums and patterns of the operator's CRDs
# (example/prometheus-operator-crd/ in prometheus-operator/prometheus-operator). Strict: a field
# not listed here is a finding, whether it is a typo or a field these checks do not know.
_DURATION = {
    "type": "string",
    "pattern": r"^(0|(([0-9]+)y)?(([0-9]+)w)?(([0-9]+)d)?(([0-9]+)h)?(([0-9]+)m)?(([0-9]+)s)?(([0-9]+)ms)?)$",
}
_KEY_REF = {
    "type": "object",
    "additionalProperties": False,
    "required": ["name", "key"],
    "properties": {"name": _STRING, "key": _STRING, "optional": _BOOLEAN},
}
_CONFIG_MAP_OR_SECRET = {
    "type": "object",
    "additionalProperties": False,
    "minProperties": 1,
    "maxProperties": 1,
    "properties": {"configMap": _KEY_REF, "secret": _KEY_REF},
}
_TLS_VERSION = {"enum": ["TLS10", "TLS11", "TLS12", "TLS13"]}
# Each relabeling action as the CRD spells it, CamelCase or lower case.
_RELABEL_ACTIONS = [
    spelling
    for action in (
        "Replace",
        "Keep",
        "Drop",
        "HashMod",
        "LabelMap",
        "LabelDrop",
        "LabelKeep",
        "Lowercase",
        "Uppercase",
        "KeepEqual",
        "DropEqual",
    )
    for spelling in (action, action.lower())
]
_RELABELINGS = {
    "type": "array",
    "items": {
        "type": "object",
        "additionalProperties": False,
        "properties": {
            "sourceLabels": {"type": "array", "items": _STRING},
            "separator": _STRING,
            "targetLabel": _STRING,
            "regex": _STRING,
            "modulus": _INT,
            "replacement": _STRING,
            "action": {"enum": _RELABEL_ACTIONS},
        },
    },
}
PODMONITOR_SCHEMA: dict[str, Any] = {
    "type": "object",
    "additionalProperties": False,
    "required": ["apiVersion", "kind", "metadata", "spec"],
    "properties": {
        "apiVersion": {"const": "monitoring.coreos.com/v1"},
        "kind": {"const": "PodMonitor"},
        "metadata": _METADATA,
        "spec": {
            "type": "object",
            "additionalProperties": False,
            "required": ["selector", "podMetricsEndpoints"],
            "properties": {
                "selector": {
                    "type": "object",
                    "additionalProperties": False,
                    "properties": {
                        "matchLabels": _STRING_MAP,
                        "matchExpressions": {
                            "type": "array",
                            "items": {
                                "type": "object",
                                "additionalProperties": False,
                                "required": ["key", "operator"],
                                "properties": {
                                    "key": _STRING,
                                    "operator": {"enum": ["In", "NotIn", "Exists", "DoesNotExist"]},
                                    "values": {"type": "array", "items": _STRING},
                                },
                            },
                        },
                    },
                },
                "namespaceSelector": {
                    "type": "object",
                    "additionalProperties": False,
                    "properties": {"any": _BOOLEAN, "matchNames": {"type": "array", "items": _STRING}},
                },
                "jobLabel": _STRING,
                "podTargetLabels": {"type": "array", "items": _STRING},
                "sampleLimit": {"type": "integer", "minimum": 0},
                "targetLimit": {"type": "integer", "minimum": 0},
                "podMetricsEndpoints": {
                    "type": "array",
                    "minItems": 1,
                    "items": {
                        "type": "object",
                        "additionalProperties": False,
                        "properties": {
                            "port": _STRING,
                            "portNumber": {"type": "integer", "minimum": 1, "maximum": 65535},
                            "path": _STRING,
                            "scheme": {"enum": ["http", "https", "HTTP", "HTTPS"]},
                            "interval": _DURATION,
                            "scrapeTimeout": _DURATION,
                            "honorLabels": _BOOLEAN,
                            "honorTimestamps": _BOOLEAN,
                            "enableHttp2": _BOOLEAN,
                            "followRedirects": _BOOLEAN,
                            "filterRunning": _BOOLEAN,
                            "params": {
                                "type": "object",
                                "additionalProperties": {"type": "array", "items": _STRING},
                            },
                            "relabelings": _RELABELINGS,
                            "metricRelabelings": _RELABELINGS,
                            "authorization": {
                                "type": "object",
                                "additionalProperties": False,
                                "properties": {"type": _STRING, "credentials": _KEY_REF},
                            },
                            "tlsConfig": {
                                "type": "object",
                                "additionalProperties": False,
                                "properties": {
                                    "ca": _CONFIG_MAP_OR_SECRET,
                                    "cert": _CONFIG_MAP_OR_SECRET,
                                    "keySecret": _KEY_REF,
                                    "serverName": _STRING,
                                    "insecureSkipVerify": _BOOLEAN,
                                    "minVersion": _TLS_VERSION,
                                    "maxVersion": _TLS_VERSION,
                                },
                            },
                        },
                    },
                },
            },
        },
    },
}
PROMETHEUS_RULE_SCHEMA: dict[str, Any] = {
    "type": "object",
    "additionalProperties": False,
    "required": ["apiVersion", "kind", "metadata", "spec"],
    "properties": {
        "apiVersion": {"const": "monitoring.coreos.com/v1"},
        "kind": {"const": "PrometheusRule"},
        "metadata": _METADATA,
        "spec": {
            "type": "object",
            "additionalProperties": False,
            "required": ["groups"],
            "properties": {
                "groups": {
                    "type": "array",
                    "minItems": 1,
                    "items": {
                        "type": "object",
                        "additionalProperties": False,
                        "required": ["name", "rules"],
                        "properties": {
                            "name": {"type": "string", "minLength": 1},
                            "interval": _DURATION,
                            "query_offset": _DURATION,
                            "limit": _INT,
                            "labels": _STRING_MAP,
                            "rules": {
                                "type": "array",
                                "minItems": 1,
                                "items": {
                                    "type": "object",
                                    "additionalProperties": False,
                                    "required": ["expr"],
                                    "properties": {
                                        "alert": _STRING,
                                        "record": _STRING,
                                        "expr": {"type": ["string", "integer"]},
                                        "for": _DURATION,
                                        "keep_firing_for": _DURATION,
                                        "labels": _STRING_MAP,
                                        "annotations": _STRING_MAP,
                                    },
                                },
                            },
                        },
                    },
                },
            },
        },
    },
}
MONITORING_SCHEMAS = {"PodMonitor": PODMONITOR_SCHEMA, "PrometheusRule": PROMETHEUS_RULE_SCHEMA}


class DeployCheckError(Exception):
    """The check itself cannot run (no renderer, an overlay kustomize refuses)."""


# --- rendering -----------------------------------------------------------------------------------


def kustomize_command() -> list[str]:
    """The command that renders a kustomization directory given as its last argument."""
    if kustomize := shutil.which("kustomize"):
        out = subprocess.run([kustomize, "version"], capture_output=True, text=True, check=False)
        if out.returncode == 0 and re.search(r"\bv5\.", out.stdout):
            return [kustomize, "build"]
    if kubectl := shutil.which("kubectl"):
        out = subprocess.run(
            [kubectl, "version", "--client", "--output=json"], capture_output=True, text=True, check=False
        )
        if out.returncode == 0:
            client = json.loads(out.stdout)
            minor = int(re.sub(r"\D.*", "", client["clientVersion"]["minor"]) or 0)
            if minor >= 27:
                return [kubectl, "kustomize"]
    raise DeployCheckError(
        "no kustomize v5 renderer: install kubectl >= 1.27 (it embeds kustomize v5; Debian's "
        "kubernetes-client 1.20 is too old) or a kustomize v5 binary, and put it on PATH"
    )


def render(directory: Path, command: list[str]) -> list[Manifest]:
    out = subprocess.run([*command, str(directory)], capture_output=True, text=True, check=False)
    if out.returncode != 0:
        raise DeployCheckError(f"kustomize refused {directory.relative_to(ROOT)}: {out.stderr.strip()}")
    return [doc for doc in yaml.safe_load_all(out.stdout) if doc is not None]


# --- schemas -------------------------------------------------------------------------------------


def where(obj: Manifest) -> str:
    return f"{obj.get('kind')}/{obj.get('metadata', {}).get('name')}"


def schema_findings(objects: list[Manifest], version: str) -> list[str]:
    findings = []
    for obj in objects:
        if obj.get("apiVersion", "").startswith("keda.sh/"):
            findings += [f"{where(obj)}: {f}" for f in scaled_object_schema_findings(obj, version)]
            continue
        if obj.get("apiVersion", "").startswith("monitoring.coreos.com/"):
            findings += [f"{where(obj)}: {f}" for f in monitoring_schema_findings(obj)]
            continue
        try:
            kubernetes_validate.validate(obj, version, strict=True)
        except kubernetes_validate.ValidationError as e:
            path = ".".join(str(p) for p in e.path)
            findings.append(f"{where(obj)}: Kubernetes {version} schema: {path}: {e.message}")
        except kubernetes_validate.SchemaNotFoundError:
            findings.append(f"{where(obj)}: no Kubernetes {version} schema for {obj.get('apiVersion')}")
    return findings


def scaled_object_schema_findings(obj: Manifest, version: str) -> list[str]:
    if obj.get("kind") != "ScaledObject":
        return [f"{obj.get('kind')} of {obj.get('apiVersion')}: no schema here (only ScaledObject)"]
    validator = jsonschema.Draft202012Validator(SCALED_OBJECT_SCHEMA)
    findings = [
        f"ScaledObject schema: {'.'.join(str(p) for p in e.path)}: {e.message}"
        for e in validator.iter_errors(obj)
    ]
    if findings:
        return findings
    spec = obj["spec"]
    for trigger in spec["triggers"]:
        if trigger["type"] != "prometheus":
            findings.append(f"trigger type {trigger['type']!r}: only prometheus is checked here")
            continue
        keys = set(trigger["metadata"])
        if missing := PROMETHEUS_TRIGGER_REQUIRED - keys:
            findings.append(f"prometheus trigger lacks {sorted(missing)}")
        if unknown := keys - PROMETHEUS_TRIGGER_KEYS:
            findings.append(f"prometheus trigger has unknown parameters {sorted(unknown)}")
    behavior = spec.get("advanced", {}).get("horizontalPodAutoscalerConfig", {}).get("behavior")
    if behavior is not None:
        hpa = {
            "apiVersion": "autoscaling/v2",
            "kind": "HorizontalPodAutoscaler",
            "metadata": {"name": "behavior-check"},
            "spec": {
                "scaleTargetRef": {"apiVersion": "apps/v1", "kind": "Deployment", "name": "x"},
                "maxReplicas": 1,
                "behavior": behavior,
            },
        }
        try:
            kubernetes_validate.validate(hpa, version, strict=True)
        except kubernetes_validate.ValidationError as e:
            findings.append(f"advanced.horizontalPodAutoscalerConfig.behavior: {e.message}")
    return findings


def monitoring_schema_findings(obj: Manifest) -> list[str]:
    schema = MONITORING_SCHEMAS.get(obj.get("kind", ""))
    if schema is None:
        known = sorted(MONITORING_SCHEMAS)
        return [f"{obj.get('kind')} of {obj.get('apiVersion')}: no schema here (only {known})"]
    validator = jsonschema.Draft202012Validator(schema)
    return [
        f"{obj['kind']} schema: {'.'.join(str(p) for p in e.path)}: {e.message}"
        for e in validator.iter_errors(obj)
    ]


# --- reading workloads ---------------------------------------------------------------------------


def pod_spec(obj: Manifest) -> Manifest | None:
    if obj.get("kind") in ("Deployment", "StatefulSet", "DaemonSet", "Job"):
        return obj["spec"]["template"]["spec"]
    if obj.get("kind") == "CronJob":
        return obj["spec"]["jobTemplate"]["spec"]["template"]["spec"]
    return None


def workloads(objects: list[Manifest]) -> Iterator[tuple[Manifest, Manifest]]:
    for obj in objects:
        if (spec := pod_spec(obj)) is not None:
            yield obj, spec


def containers(spec: Manifest) -> list[Manifest]:
    return [*spec.get("initContainers", []), *spec.get("containers", [])]


def argv(container: Manifest) -> list[str]:
    return [*container.get("command", []), *container.get("args", [])]


def program(container: Manifest) -> str:
    args = argv(container)
    return args[0] if args else ""


def flag(container: Manifest, name: str) -> str | None:
    """The value of `--name=value` or `--name value`; "" for a bare `--name`; None if absent."""
    args = argv(container)
    for i, arg in enumerate(args):
        if arg.startswith(f"{name}="):
            return arg.split("=", 1)[1]
        if arg == name:
            following = args[i + 1] if i + 1 < len(args) else ""
            return "" if following.startswith("--") else following
    return None


def env_entry(container: Manifest, name: str) -> Manifest | None:
    return next((e for e in container.get("env", []) if e["name"] == name), None)


def env_value(container: Manifest, name: str, objects: list[Manifest]) -> str | None:
    """An env var's literal value, or the ConfigMap key it refers to when that ConfigMap is rendered."""
    entry = env_entry(container, name)
    if entry is None:
        return None
    if "value" in entry:
        return str(entry["value"])
    ref = entry.get("valueFrom", {}).get("configMapKeyRef")
    if ref is None:
        return None
    for obj in objects:
        if obj["kind"] == "ConfigMap" and obj["metadata"]["name"] == ref["name"]:
            return obj.get("data", {}).get(ref["key"])
    return None


def mebibytes(quantity: str | int) -> float:
    """A Kubernetes memory quantity in MiB."""
    units = {"Ki": 2**10, "Mi": 2**20, "Gi": 2**30, "Ti": 2**40, "k": 1e3, "M": 1e6, "G": 1e9, "T": 1e12}
    match = re.fullmatch(r"(\d+(?:\.\d+)?)([KMGT]i|[kMGT])?", str(quantity))
    if match is None:
        raise ValueError(f"not a memory quantity: {quantity!r}")
    number, unit = match.groups()
    return float(number) * (units[unit] if unit else 1) / 2**20


def references(spec: Manifest) -> Iterator[tuple[str, str, str | None, bool]]:
    """(kind, name, key, optional) for every Secret and ConfigMap a pod spec refers to."""
    for container in containers(spec):
        for entry in container.get("env", []):
            source = entry.get("valueFrom", {})
            for field, kind in (("secretKeyRef", "Secret"), ("configMapKeyRef", "ConfigMap")):
                if ref := source.get(field):
                    yield kind, ref["name"], ref["key"], bool(ref.get("optional"))
        for entry in container.get("envFrom", []):
            for field, kind in (("secretRef", "Secret"), ("configMapRef", "ConfigMap")):
                if ref := entry.get(field):
                    yield kind, ref["name"], None, bool(ref.get("optional"))
    for volume in spec.get("volumes", []):
        if secret := volume.get("secret"):
            yield "Secret", secret["secretName"], None, bool(secret.get("optional"))
        if config_map := volume.get("configMap"):
            yield "ConfigMap", config_map["name"], None, bool(config_map.get("optional"))


def image_parts(image: str) -> tuple[str, str | None, str | None]:
    """(repository, tag, digest) of an image reference."""
    name, _, digest = image.partition("@")
    last = name.rsplit("/", 1)[-1]
    tag = last.split(":", 1)[1] if ":" in last else None
    repository = name[: len(name) - len(tag) - 1] if tag is not None else name
    return repository, tag, digest or None


def selects(selector: Manifest, labels: Manifest) -> bool:
    match_labels = selector.get("matchLabels", selector)
    return bool(match_labels) and all(labels.get(k) == v for k, v in match_labels.items())


# --- metrics and PromQL ------------------------------------------------------------------------------

# A Rust string or char literal, or a comment: what the metric reader must not read as code.
_RUST_TOKENS = re.compile(r"""'(?:\\.|[^'\\])'|"(?:\\.|[^"\\])*"|//[^\n]*|/\*.*?\*/""", re.DOTALL)
# The metric types prometheus-client registers, and the words in Rust that say which one it is.
_RUST_METRIC_TYPES = (
    ("info", re.compile(r"\bInfo\b")),
    ("histogram", re.compile(r"\b[Hh]istogram")),
    ("counter", re.compile(r"\bCounter\b")),
    ("gauge", re.compile(r"\bGauge\b")),
)
# The series names each type is exposed under, from its registered name (prometheus-client adds
# the suffix); a registration whose type this reading cannot tell may be any of them.
EXPOSED_SUFFIXES = {
    "counter": ("_total",),
    "gauge": ("",),
    "histogram": ("_bucket", "_count", "_sum"),
    "info": ("_info",),
    "": ("", "_total", "_bucket", "_count", "_sum", "_info"),
}


def _metric_types(code: str) -> set[str]:
    return {kind for kind, pattern in _RUST_METRIC_TYPES if pattern.search(code)}


def _rust_type_at(code: str, start: int) -> str:
    """The type written at `start` (after `name:`), up to the first `,` `;` `=` `{` `)` or line end
    outside its angle brackets."""
    depth = 0
    for end in range(start, len(code)):
        char = code[end]
        depth += {"<": 1, ">": -1}.get(char, 0)
        if depth <= 0 and char in ",;={)\n":
            return code[start:end]
    return code[start:]


def registered_metrics(source: str) -> dict[str, str]:
    """The `vint_*` metrics one Rust file registers (its `#[cfg(test)]` part left out): {registered name:
    type}, the type "" when neither the registering statement nor the declared type of what it
    registers names one.

    A registration is a statement that names `register` or `registry` and holds a string literal
    `vint_…`: `registry.register("vint_jobs", "help", Family::clone(&jobs))`, or a helper such as
    `histogram(&mut registry, "vint_worker_fetch_seconds", "help")`. Its type is the one the
    statement names (`Counter::default()`, `Info::new`, `histogram(`), else the one the declarations
    of the identifiers it uses name (`jobs: Family<JobLabels, Gauge>`).
    """
    literals: list[str] = []

    def placeholder(match: re.Match[str]) -> str:
        token = match.group(0)
        if token.startswith('"'):
            literals.append(token[1:-1])
            return f'"{len(literals) - 1}"'
        return " " if token.startswith("/") else "''"

    code = _RUST_TOKENS.sub(placeholder, source.split("#[cfg(test)]", 1)[0])
    found: dict[str, str] = {}
    for statement in code.split(";"):
        if not re.search(r"\bregist(?:er|ry)\b", statement):
            continue
        names = [
            literals[int(i)]
            for i in re.findall(r'"(\d+)"', statement)
            if re.fullmatch(r"vint_[a-z0-9_]+", literals[int(i)])
        ]
        if not names:
            continue
        kinds = _metric_types(statement)
        if not kinds:
            for identifier in set(re.findall(r"\b[a-z_][a-z0-9_]*\b", statement)):
                for declared in re.finditer(rf"(?<!:)\b{identifier}\s*:(?!:)", code):
                    kinds |= _metric_types(_rust_type_at(code, declared.end()))
                for declared in re.finditer(rf"\blet\s+(?:mut\s+)?{identifier}\s*=\s*([^;]+)", code):
                    kinds |= _metric_types(declared.group(1))
        for name in names:
            found[name] = kinds.pop() if len(kinds) == 1 else ""
    return found


@cache
def exported_metrics(sources: tuple[Path, ...] = METRIC_SOURCES) -> frozenset[str]:
    """Every series name a vint process exports, as a query names it (`vint_tasks_completed_total`,
    `vint_queue_tasks`, `vint_rpc_duration_seconds_bucket`), read from the Rust sources."""
    names: set[str] = set()
    for directory in sources:
        for path in sorted(directory.rglob("*.rs")):
            for name, kind in registered_metrics(path.read_text(encoding="utf-8")).items():
                names.update(name + suffix for suffix in EXPOSED_SUFFIXES[kind])
    return frozenset(names)


_PROMQL_STRING = re.compile(r""""(?:\\.|[^"\\])*"|'(?:\\.|[^'\\])*'|`[^`]*`""")
# Words of PromQL that are not series names: aggregations (which may take `by (…)` before their
# parenthesis), binary operators and modifiers, and the float literals.
PROMQL_KEYWORDS = frozenset(
    {
        "sum",
        "min",
        "max",
        "avg",
        "group",
        "stddev",
        "stdvar",
        "count",
        "count_values",
        "bottomk",
        "topk",
        "quantile",
        "limitk",
        "limit_ratio",
        "by",
        "without",
        "on",
        "ignoring",
        "group_left",
        "group_right",
        "and",
        "or",
        "unless",
        "atan2",
        "bool",
        "offset",
        "inf",
        "nan",
    }
)


def promql_findings(expr: str) -> list[str]:
    """What is lexically wrong with a PromQL expression: empty, an unclosed string, unbalanced brackets.
    (No PromQL parser is a Python package; Prometheus parses the rest when it loads the rule.)"""
    if not expr.strip():
        return ["the expression is empty"]
    closing = {"(": ")", "[": "]", "{": "}"}
    stack: list[str] = []
    at = 0
    while at < len(expr):
        char = expr[at]
        if char in "\"'`":
            end = at + 1
            while end < len(expr) and expr[end] != char:
                end += 2 if expr[end] == "\\" and char != "`" else 1
            if end >= len(expr):
                return [f"a string opened at character {at} is never closed"]
            at = end
        elif char in closing:
            stack.append(closing[char])
        elif char in ")]}" and (not stack or stack.pop() != char):
            return [f"unbalanced {char!r} at character {at}"]
        at += 1
    return [f"unclosed brackets, {''.join(reversed(stack))!r} missing"] if stack else []


def promql_metrics(expr: str) -> set[str]:
    """The series names a PromQL expression reads: its identifiers, less strings, label matchers,
    ranges, grouping labels, function calls and keywords."""
    text = _PROMQL_STRING.sub('""', expr)
    text = re.sub(r"#[^\n]*", " ", text)
    text = re.sub(r"\{[^{}]*\}", "{}", text)
    text = re.sub(r"\[[^\[\]]*\]", "[]", text)
    text = re.sub(r"\b(by|without|on|ignoring|group_left|group_right)\s*\([^()]*\)", r"\1", text)
    text = re.sub(r"\boffset\s+-?\w+", " ", text)
    text = re.sub(r"@\s*(?:\w+\(\)|[\d.]+)", " ", text)
    names = set()
    for match in re.finditer(r"(?<![\w.:])[A-Za-z_:][\w:]*", text):
        name = match.group(0)
        if name.lower() in PROMQL_KEYWORDS or re.match(r"\s*\(", text[match.end() :]):
            continue
        names.add(name)
    return names


def doc_section(text: str, title: str) -> str:
    """The body of the Markdown section titled `title` (to the next heading of its level or above)."""
    lines = text.splitlines()
    for i, line in enumerate(lines):
        heading = re.match(r"(#+)\s+(.*?)\s*$", line)
        if heading and heading.group(2) == title:
            level = len(heading.group(1))
            end = next(
                (
                    j
                    for j in range(i + 1, len(lines))
                    if (h := re.match(r"(#+)\s", lines[j])) and len(h.group(1)) <= level
                ),
                len(lines),
            )
            return "\n".join(lines[i + 1 : end])
    return ""


@cache
def operations_doc() -> str:
    return OPERATIONS_DOC.read_text(encoding="utf-8")


# --- the rules -----------------------------------------------------------------------------------


def container_findings(obj: Manifest, spec: Manifest, container: Manifest) -> list[str]:
    """Security context, resources, image and probes every container must have."""
    at = f"{where(obj)} container {container['name']}"
    findings = []
    pod_security = spec.get("securityContext", {})
    security = container.get("securityContext", {})
    if not (security.get("runAsNonRoot") or pod_security.get("runAsNonRoot")):
        findings.append(f"{at}: runAsNonRoot is not true")
    seccomp = security.get("seccompProfile") or pod_security.get("seccompProfile") or {}
    if seccomp.get("type") != "RuntimeDefault":
        findings.append(f"{at}: seccompProfile is not RuntimeDefault")
    if security.get("allowPrivilegeEscalation") is not False:
        findings.append(f"{at}: allowPrivilegeEscalation is not false")
    if security.get("readOnlyRootFilesystem") is not True:
        findings.append(f"{at}: readOnlyRootFilesystem is not true")
    if "ALL" not in security.get("capabilities", {}).get("drop", []):
        findings.append(f"{at}: capabilities do not drop ALL")

    resources = container.get("resources", {})
    requests, limits = resources.get("requests", {}), resources.get("limits", {})
    for missing in ({"cpu", "memory"} - set(requests)) | ({"memory"} - set(limits)):
        kind = "limit" if missing == "memory" and "memory" in requests else "request"
        findings.append(f"{at}: no {missing} {kind}")
    if (
        "memory" in requests
        and "memory" in limits
        and mebibytes(limits["memory"]) < mebibytes(requests["memory"])
    ):
        findings.append(f"{at}: memory limit {limits['memory']} is below its request {requests['memory']}")

    image = container.get("image", "")
    _, tag, digest = image_parts(image)
    if tag is None and digest is None:
        findings.append(f"{at}: image {image!r} has neither tag nor digest (set it with kustomize `images:`)")
    if tag == "latest":
        findings.append(f"{at}: image {image!r} floats on :latest")

    if obj["kind"] in ("Deployment", "StatefulSet", "DaemonSet") and container in spec.get("containers", []):
        for probe in ("readinessProbe", "livenessProbe"):
            if probe not in container:
                findings.append(f"{at}: no {probe}")
    return findings


def worker_findings(obj: Manifest, spec: Manifest, container: Manifest, objects: list[Manifest]) -> list[str]:
    at = f"{where(obj)}"
    findings = []
    grace = spec.get("terminationGracePeriodSeconds", 30)
    if grace < HAND_BACK_BOUND_S:
        findings.append(
            f"{at}: terminationGracePeriodSeconds {grace} is below the {HAND_BACK_BOUND_S} s hand-back"
        )

    for entry in container.get("env", []):
        ref = entry.get("valueFrom", {}).get("secretKeyRef", {})
        if "DATABASE" in entry["name"] or ref.get("name", "").startswith(("vint-database", "vint-postgres")):
            findings.append(f"{at}: workers never read the database, yet env {entry['name']} is set")
    if container.get("envFrom"):
        findings.append(
            f"{at}: envFrom hands the worker every key of a ConfigMap/Secret; name the keys it reads"
        )
    for kind, name, _, _ in references(spec):
        if kind == "Secret" and name.startswith(("vint-database", "vint-postgres")):
            findings.append(f"{at}: the worker mounts database Secret {name}")

    stages = (flag(container, "--stages") or "").split(",")
    label = obj["spec"]["template"]["metadata"].get("labels", {}).get("vint/stage")
    if len(stages) != 1 or stages[0] not in STAGES or stages[0] != label:
        findings.append(f"{at}: --stages {stages} is not the single stage of its vint/stage label {label!r}")
    stage = stages[0]

    limit = container.get("resources", {}).get("limits", {}).get("memory")
    if stage in ENGINE_STAGES:
        bound = env_value(container, "VINT_ENGINE_MAX_RSS_MIB", objects) or flag(
            container, "--engine-max-rss-mib"
        )
        if bound is None:
            findings.append(
                f"{at}: engine memory bound not set (VINT_ENGINE_MAX_RSS_MIB; the default is 8192)"
            )
        elif limit is not None and mebibytes(limit) < int(bound) + WORKER_HEADROOM_MIB:
            findings.append(
                f"{at}: memory limit {limit} does not fit the engine bound {bound} MiB "
                f"+ {WORKER_HEADROOM_MIB} MiB for the worker"
            )

    listen = flag(container, "--metrics-listen")
    port = int(listen.rsplit(":", 1)[1]) if listen else None
    if port is None:
        findings.append(f"{at}: no --metrics-listen (its /healthz is what the probes ask)")
    ports = {p.get("name"): p["containerPort"] for p in container.get("ports", [])}
    for probe in ("readinessProbe", "livenessProbe"):
        get = container.get(probe, {}).get("httpGet", {})
        probed = ports.get(get.get("port"), get.get("port"))
        if get.get("path") != "/healthz" or probed != port:
            findings.append(f"{at}: {probe} does not ask /healthz on the --metrics-listen port {port}")

    mounts = {m["mountPath"]: m["name"] for m in container.get("volumeMounts", [])}
    empty_dirs = {v["name"] for v in spec.get("volumes", []) if "emptyDir" in v}
    for path in (flag(container, "--scratch"), "/tmp"):
        if path is None or mounts.get(path) not in empty_dirs:
            findings.append(f"{at}: {path} is not a writable emptyDir (the root filesystem is read-only)")

    if (
        env_value(container, "VINT_COORDINATOR", objects) is None
        and env_entry(container, "VINT_COORDINATOR") is None
    ):
        findings.append(f"{at}: no VINT_COORDINATOR")
    token = (env_entry(container, "VINT_TOKEN") or {}).get("valueFrom", {}).get("secretKeyRef")
    if token is None:
        findings.append(f"{at}: VINT_TOKEN does not come from a Secret")
    return findings


def coordinator_findings(obj: Manifest, spec: Manifest, container: Manifest, overlay: Overlay) -> list[str]:
    at = where(obj)
    findings = []
    if flag(container, "--no-migrate") is None or flag(container, "--migrate-only") is not None:
        findings.append(f"{at}: replicas must run with --no-migrate (the migration Job runs DDL)")
    if flag(container, "--auth-tokens") is None or flag(container, "--insecure-listen-any") is not None:
        findings.append(f"{at}: the coordinator must listen with --auth-tokens, not --insecure-listen-any")
    grace = spec.get("terminationGracePeriodSeconds", 30)
    if grace <= COORDINATOR_DRAIN_S:
        findings.append(
            f"{at}: terminationGracePeriodSeconds {grace} is not above the {COORDINATOR_DRAIN_S} s drain"
        )
    replicas = obj["spec"].get("replicas", 1)
    if replicas < overlay.min_coordinators:
        findings.append(f"{at}: {replicas} replica(s); {overlay.name} promises {overlay.min_coordinators}")
    database = (env_entry(container, "VINT_DATABASE_URL") or {}).get("valueFrom", {}).get("secretKeyRef", {})
    if not database.get("name", "").startswith("vint-database") or "migrate" in database.get("name", ""):
        findings.append(f"{at}: VINT_DATABASE_URL must come from the vint-database Secret (DML rights only)")
    readiness, liveness = container.get("readinessProbe", {}), container.get("livenessProbe", {})
    if (
        readiness.get("grpc", {}).get("service") not in API_SERVICES
        and readiness.get("httpGet", {}).get("path") != "/healthz"
    ):
        findings.append(
            f"{at}: readinessProbe does not follow the database (an API's gRPC health or /healthz)"
        )
    if liveness.get("grpc", {}).get("service") or "httpGet" in liveness:
        findings.append(f"{at}: livenessProbe follows the database: an outage would restart every replica")
    if flag(container, "--tls-cert") is not None:
        for probe in ("startupProbe", "readinessProbe", "livenessProbe"):
            if "grpc" in container.get(probe, {}):
                findings.append(
                    f"{at}: {probe} is a grpc probe, which the kubelet sends in plaintext to a TLS port"
                )
    return findings


def overlay_findings(
    overlay: Overlay, objects: list[Manifest], readme: str, operations: str | None = None
) -> list[str]:
    """Every rule, over one rendered overlay (`operations`: docs/operations.md's text, read if None)."""
    findings = []
    by_kind: dict[str, list[Manifest]] = {}
    for obj in objects:
        by_kind.setdefault(obj["kind"], []).append(obj)
    rendered = {(o["kind"], o["metadata"]["name"]): o for o in objects}

    coordinators, workers, migrations = [], [], []
    externals: set[tuple[str, str]] = set()
    for obj, spec in workloads(objects):
        if spec.get("automountServiceAccountToken") is not False:
            findings.append(f"{where(obj)}: automountServiceAccountToken is not false")
        for container in containers(spec):
            findings += container_findings(obj, spec, container)
            match program(container), obj["kind"]:
                case "vint-worker", "Deployment":
                    workers.append(obj)
                    findings += worker_findings(obj, spec, container, objects)
                case "vint-coordinator", "Deployment":
                    coordinators.append(obj)
                    findings += coordinator_findings(obj, spec, container, overlay)
                case "vint-coordinator", "Job":
                    migrations.append((obj, container))
                case (("vint-worker" | "vint-coordinator"), kind):
                    findings.append(f"{where(obj)}: {program(container)} as a {kind}")

        for kind, name, key, optional in references(spec):
            target = rendered.get((kind, name))
            if target is None:
                if not overlay.external_secrets:
                    findings.append(
                        f"{where(obj)}: refers to {kind} {name}, which {overlay.name} does not make"
                    )
                elif name not in (EXTERNAL_SECRETS if kind == "Secret" else EXTERNAL_CONFIGMAPS):
                    findings.append(
                        f"{where(obj)}: refers to {kind} {name}: not rendered, not a known external one"
                    )
                else:
                    externals.add((kind, name))
            elif key is not None and not optional:
                data = {**target.get("data", {}), **target.get("stringData", {})}
                if key not in data:
                    findings.append(f"{where(obj)}: {kind} {name} has no key {key}")

    for kind, name in sorted(externals):
        if f"`{name}`" not in readme:
            findings.append(f"{kind} {name}, created out of band, is not documented in deploy/README.md")
    if overlay.external_secrets and (secrets := by_kind.get("Secret")):
        findings.append(
            f"Secrets {[s['metadata']['name'] for s in secrets]} are part of {overlay.name}: "
            "re-applying it would overwrite real credentials"
        )

    if len(coordinators) != 1:
        findings.append(f"{len(coordinators)} coordinator Deployments; expected 1")
    if len(migrations) != 1:
        findings.append(f"{len(migrations)} migration Jobs; expected 1")
    for job, container in migrations:
        database = (
            (env_entry(container, "VINT_DATABASE_URL") or {}).get("valueFrom", {}).get("secretKeyRef", {})
        )
        if flag(container, "--migrate-only") is None:
            findings.append(f"{where(job)}: the migration Job must run --migrate-only")
        if database.get("name") != "vint-database-migrate" and not database.get("name", "").startswith(
            "vint-database-migrate-"
        ):
            findings.append(
                f"{where(job)}: VINT_DATABASE_URL must come from vint-database-migrate (the schema owner)"
            )

    worker_stages = sorted(
        w["spec"]["template"]["metadata"]["labels"].get("vint/stage", "?") for w in workers
    )
    if worker_stages != sorted(STAGES):
        findings.append(
            f"worker Deployments for stages {worker_stages}; expected one per stage {sorted(STAGES)}"
        )

    for coordinator in coordinators:
        labels = coordinator["spec"]["template"]["metadata"]["labels"]
        if not any(selects(p["spec"]["selector"], labels) for p in by_kind.get("PodDisruptionBudget", [])):
            findings.append(f"{where(coordinator)}: no PodDisruptionBudget")
        services = [s for s in by_kind.get("Service", []) if selects(s["spec"].get("selector", {}), labels)]
        if not any(p["port"] == 7700 for s in services for p in s["spec"]["ports"]):
            findings.append(f"{where(coordinator)}: no Service on 7700")
        tls = flag(coordinator["spec"]["template"]["spec"]["containers"][0], "--tls-cert") is not None
        for worker in workers:
            container = worker["spec"]["template"]["spec"]["containers"][0]
            address = env_value(container, "VINT_COORDINATOR", objects) or ""
            scheme = "https://" if tls else "http://"
            if not address.startswith(scheme):
                findings.append(
                    f"{where(worker)}: VINT_COORDINATOR {address!r} is not {scheme} (coordinator TLS: {tls})"
                )
            if tls and env_entry(container, "VINT_TLS_CA") is None:
                findings.append(f"{where(worker)}: no VINT_TLS_CA to trust the coordinator's certificate")

    if not any(
        p["spec"]["podSelector"] == {}
        and p["spec"].get("policyTypes") == ["Ingress"]
        and not p["spec"].get("ingress")
        for p in by_kind.get("NetworkPolicy", [])
    ):
        findings.append("no default-deny ingress NetworkPolicy")

    findings += autoscaling_findings(overlay, workers, by_kind.get("ScaledObject", []))
    findings += gpu_findings(overlay, workers)
    findings += monitoring_findings(
        overlay, objects, coordinators + workers, operations_doc() if operations is None else operations
    )
    return findings


def autoscaling_findings(overlay: Overlay, workers: list[Manifest], scaled: list[Manifest]) -> list[str]:
    findings = []
    if not overlay.autoscaled:
        if scaled:
            findings.append(f"ScaledObjects in {overlay.name}, which has no KEDA")
        for worker in workers:
            if worker["spec"].get("replicas", 0) < 1:
                findings.append(f"{where(worker)}: neither autoscaled nor given replicas")
        return findings
    for worker in workers:
        name = worker["metadata"]["name"]
        stage = worker["spec"]["template"]["metadata"]["labels"].get("vint/stage")
        targeting = [s for s in scaled if s["spec"]["scaleTargetRef"]["name"] == name]
        if len(targeting) != 1:
            findings.append(f"{where(worker)}: {len(targeting)} ScaledObjects target it; expected 1")
            continue
        if "replicas" in worker["spec"]:
            findings.append(
                f"{where(worker)}: sets replicas, which its ScaledObject owns (every apply would reset it)"
            )
        spec = targeting[0]["spec"]
        if spec.get("minReplicaCount", 0) > spec.get("maxReplicaCount", 100):
            findings.append(f"{where(targeting[0])}: minReplicaCount above maxReplicaCount")
        for trigger in spec["triggers"]:
            query = trigger["metadata"].get("query", "")
            if "vint_queue_tasks" not in query or f'stage="{stage}"' not in query:
                findings.append(f"{where(targeting[0])}: query {query!r} is not {stage}'s queue depth")
            if not re.match(r"https?://", trigger["metadata"].get("serverAddress", "")):
                findings.append(f"{where(targeting[0])}: serverAddress is not an http(s) URL")
    targets = {w["metadata"]["name"] for w in workers}
    for s in scaled:
        if s["spec"]["scaleTargetRef"]["name"] not in targets:
            findings.append(
                f"{where(s)}: targets {s['spec']['scaleTargetRef']['name']}, which is not a worker"
            )
    return findings


def gpu_findings(overlay: Overlay, workers: list[Manifest]) -> list[str]:
    findings = []
    for worker in workers:
        spec = worker["spec"]["template"]["spec"]
        gpus = spec["containers"][0].get("resources", {}).get("limits", {}).get("nvidia.com/gpu")
        wants_gpu = (
            overlay.gpu_render
            and worker["spec"]["template"]["metadata"]["labels"].get("vint/stage") == "render"
        )
        if wants_gpu and (gpus is None or int(gpus) < 1):
            findings.append(f"{where(worker)}: no nvidia.com/gpu limit in {overlay.name}")
        if wants_gpu and not any(t.get("key") == "nvidia.com/gpu" for t in spec.get("tolerations", [])):
            findings.append(f"{where(worker)}: no toleration for the GPU nodes' nvidia.com/gpu taint")
        if not wants_gpu and gpus is not None:
            findings.append(f"{where(worker)}: asks for a GPU in {overlay.name}")
    return findings


def monitoring_findings(
    overlay: Overlay,
    objects: list[Manifest],
    scraped: list[Manifest],
    operations: str,
) -> list[str]:
    """PodMonitors that scrape every coordinator and worker where it serves /metrics, and alerts over
    metrics that exist, each documented in docs/operations.md. `scraped`: the coordinator and worker
    Deployments."""
    monitors = [o for o in objects if o["kind"] == "PodMonitor"]
    rules = [o for o in objects if o["kind"] == "PrometheusRule"]
    if not overlay.monitored:
        return [
            f"{where(o)} in {overlay.name}, which promises no Prometheus Operator" for o in monitors + rules
        ]
    findings = []
    rendered = {(o["kind"], o["metadata"]["name"]) for o in objects}
    metrics = exported_metrics()
    jobs: set[str] = set()
    used: set[str] = set()
    for workload in scraped:
        labels = workload["spec"]["template"]["metadata"].get("labels", {})
        selecting = [m for m in monitors if selects(m["spec"]["selector"], labels)]
        if len(selecting) != 1:
            findings.append(f"{where(workload)}: {len(selecting)} PodMonitors select its pods; expected 1")
            continue
        monitor = selecting[0]
        used.add(monitor["metadata"]["name"])
        meta = monitor["metadata"]
        job_label = monitor["spec"].get("jobLabel")
        # The operator names the job after the pod's jobLabel, else `<namespace>/<PodMonitor name>`.
        jobs.add(labels[job_label] if job_label in labels else f"{meta.get('namespace', '')}/{meta['name']}")
        container = workload["spec"]["template"]["spec"]["containers"][0]
        coordinator = program(container) == "vint-coordinator"
        listen_flag = "--http-listen" if coordinator else "--metrics-listen"
        listen = flag(container, listen_flag)
        port = int(listen.rsplit(":", 1)[1]) if listen else None
        ports = {p.get("name"): p["containerPort"] for p in container.get("ports", [])}
        https = coordinator and flag(container, "--tls-cert") is not None
        at = f"{where(monitor)} on {where(workload)}"
        for endpoint in monitor["spec"]["podMetricsEndpoints"]:
            named = endpoint.get("port", endpoint.get("portNumber"))
            target = ports.get(endpoint["port"]) if "port" in endpoint else endpoint.get("portNumber")
            if port is None or target != port:
                findings.append(f"{at}: scrapes port {named!r}, not the {listen_flag} port {port}")
            if endpoint.get("path", "/metrics") != "/metrics":
                findings.append(f"{at}: scrapes {endpoint['path']}, not /metrics")
            scheme = endpoint.get("scheme", "http").lower()
            if scheme != ("https" if https else "http"):
                serves = "HTTPS (--tls-cert)" if https else "plain HTTP"
                findings.append(f"{at}: scrapes with {scheme}, but the pod serves {serves}")
            tls = endpoint.get("tlsConfig", {})
            if https and (tls.get("insecureSkipVerify") or "ca" not in tls or not tls.get("serverName")):
                findings.append(
                    f"{at}: an HTTPS scrape needs tlsConfig.ca and serverName (and no insecureSkipVerify)"
                )
            for field, kind, external in (
                ("configMap", "ConfigMap", EXTERNAL_CONFIGMAPS),
                ("secret", "Secret", EXTERNAL_SECRETS),
            ):
                name = tls.get("ca", {}).get(field, {}).get("name")
                if name is not None and (kind, name) not in rendered and name not in external:
                    findings.append(f"{at}: its CA is {kind} {name}: not rendered, not a known external one")
    for monitor in monitors:
        if monitor["metadata"]["name"] not in used:
            findings.append(f"{where(monitor)}: selects no coordinator or worker pod")
        for endpoint in monitor["spec"]["podMetricsEndpoints"]:
            for relabeling in endpoint.get("metricRelabelings", []):
                if relabeling.get("sourceLabels") != ["__name__"]:
                    continue
                for name in re.split(r"[|()^$]", relabeling.get("regex", "")):
                    if re.fullmatch(r"[A-Za-z_:][\w:]*", name) and name not in metrics:
                        findings.append(
                            f"{where(monitor)}: metricRelabelings name {name}, which no vint process exports"
                        )
    if not any(r.get("alert") for o in rules for g in o["spec"]["groups"] for r in g["rules"]):
        findings.append(f"no PrometheusRule with alerts in {overlay.name}")
    documented = doc_section(operations, ALERTS_SECTION)
    for rule in rules:
        findings += prometheus_rule_findings(rule, metrics, jobs)
        for group in rule["spec"]["groups"]:
            for alert in (r["alert"] for r in group["rules"] if r.get("alert")):
                if f"`{alert}`" not in documented:
                    findings.append(
                        f"{where(rule)} {alert}: not documented in {OPERATIONS_DOC.relative_to(ROOT)}, "
                        f'section "{ALERTS_SECTION}"'
                    )
    return findings


def prometheus_rule_findings(rule: Manifest, metrics: frozenset[str], jobs: set[str]) -> list[str]:
    """Every rule: a non-empty expression over series that exist (`metrics`, EXTERNAL_METRICS, or
    recorded by a rule here) and jobs a PodMonitor makes (`jobs`); every alert: `for`, a severity, a
    summary and a description that points at its runbook."""
    findings = []
    groups = rule["spec"]["groups"]
    recorded = {r["record"] for g in groups for r in g["rules"] if r.get("record")}
    known = metrics | EXTERNAL_METRICS.keys() | recorded
    alerts: set[str] = set()
    for group in groups:
        for entry in group["rules"]:
            name = entry.get("alert") or entry.get("record") or "?"
            at = f"{where(rule)} {name}"
            if bool(entry.get("alert")) == bool(entry.get("record")):
                findings.append(f"{at}: has both or neither of alert and record (a rule is one of them)")
            expr = str(entry.get("expr", ""))
            findings += [f"{at}: {f}" for f in promql_findings(expr)]
            for metric in sorted(promql_metrics(expr) - known):
                findings.append(
                    f"{at}: reads {metric}, which no vint process exports and which is not one of "
                    f"{sorted(EXTERNAL_METRICS)}"
                )
            for job in re.findall(r'\bjob\s*=\s*"([^"]*)"', expr):
                if job not in jobs:
                    findings.append(
                        f"{at}: reads job {job!r}, which no PodMonitor here makes ({sorted(jobs)})"
                    )
            if not entry.get("alert"):
                continue
            if name in alerts:
                findings.append(f"{at}: a second alert of that name")
            alerts.add(name)
            if not entry.get("for"):
                findings.append(f"{at}: no `for`: one bad evaluation would fire it")
            if entry.get("labels", {}).get("severity") not in ALERT_SEVERITIES:
                findings.append(f"{at}: labels.severity is not one of {sorted(ALERT_SEVERITIES)}")
            annotations = entry.get("annotations", {})
            for key in ("summary", "description"):
                if not str(annotations.get(key, "")).strip():
                    findings.append(f"{at}: no annotations.{key}")
            if "docs/operations.md" not in annotations.get("description", ""):
                findings.append(f"{at}: its description does not name its runbook in docs/operations.md")
    return findings


def docs_findings(base: list[Manifest], readme: str, operations: str) -> list[str]:
    """The docs quote the query the shipped ScaledObjects scale on, word for word."""
    findings = []
    for scaled in (o for o in base if o["kind"] == "ScaledObject"):
        if scaled["metadata"]["name"] != "vint-worker-render":
            continue
        for trigger in scaled["spec"]["triggers"]:
            query = trigger["metadata"].get("query", "")
            for doc, text in (
                ("deploy/README.md", readme),
                (str(OPERATIONS_DOC.relative_to(ROOT)), operations),
            ):
                if query not in text:
                    findings.append(f"{doc} does not quote {where(scaled)}'s query {query!r}")
    return findings


def base_findings(objects: list[Manifest]) -> list[str]:
    secrets = [o["metadata"]["name"] for o in objects if o["kind"] == "Secret"]
    return [f"base contains Secrets {secrets}"] if secrets else []


# --- the image -----------------------------------------------------------------------------------


def dockerfile_findings(dockerfile: str, dockerignore: str) -> list[str]:
    """What deploy/Dockerfile must do, read from its text (no container runtime builds it here)."""
    findings = []
    text = re.sub(r"\\\n", " ", dockerfile)
    instructions = [
        line.strip() for line in text.splitlines() if line.strip() and not line.lstrip().startswith("#")
    ]
    args = dict(re.findall(r"^ARG\s+(\w+)=(\S+)", text, flags=re.MULTILINE))
    stages: set[str] = set()
    for line in instructions:
        if not line.upper().startswith("FROM "):
            continue
        words = line.split()
        image = words[1]
        image = re.sub(r"\$\{?(\w+)\}?", lambda m: args.get(m.group(1), m.group(0)), image)
        if len(words) >= 4 and words[2].upper() == "AS":
            stages.add(words[3])
        if image in stages:
            continue
        _, tag, digest = image_parts(image)
        if digest is None and (tag is None or not re.match(r"\d+\.\d+\.\d+", tag)):
            findings.append(f"Dockerfile: base image {image} is not pinned to an exact version or digest")
    builds = [line for line in instructions if "cargo build" in line]
    if not builds or not all("--locked" in line for line in builds):
        findings.append("Dockerfile: cargo build without --locked")
    if not any("type=cache" in line and "cargo/registry" in line for line in builds):
        findings.append("Dockerfile: no cache mount for the cargo registry (dependencies rebuilt every time)")
    users = [line.split()[1] for line in instructions if line.upper().startswith("USER ")]
    uid = users[-1].split(":")[0] if users else "0"
    if not uid.isdigit() or int(uid) == 0:
        findings.append(
            f"Dockerfile: the final image runs as {uid!r}, not a numeric non-root uid (runAsNonRoot)"
        )
    ignored = {
        line.strip().strip("/")
        for line in dockerignore.splitlines()
        if line.strip() and not line.startswith("#")
    }
    for path in ("target", ".venv", ".git"):
        if path not in ignored:
            findings.append(f".dockerignore: {path} is sent to the build")
    for path in sorted(ignored & BUILD_INPUTS):
        findings.append(f".dockerignore: {path} is left out, but the build reads it")
    return findings


# --- main ----------------------------------------------------------------------------------------


def all_findings() -> tuple[list[str], list[str]]:
    """(findings, a line per overlay saying what was checked)."""
    command = kustomize_command()
    readme = (DEPLOY / "README.md").read_text()
    findings: list[str] = []
    checked: list[str] = []
    targets: list[tuple[str, Overlay | None]] = [("base", None)] + [(o.name, o) for o in OVERLAYS]
    for name, overlay in targets:
        directory = K8S / "base" if overlay is None else K8S / "overlays" / name
        objects = render(directory, command)
        found = [] if overlay is None else overlay_findings(overlay, objects, readme)
        if overlay is None:
            found += base_findings(objects) + docs_findings(objects, readme, operations_doc())
        for version in KUBERNETES_VERSIONS:
            found += schema_findings(objects, version)
        findings += [f"{name}: {f}" for f in dict.fromkeys(found)]
        checked.append(
            f"{name}: {len(objects)} objects, Kubernetes {' and '.join(KUBERNETES_VERSIONS)} schemas"
        )
    dockerignore = ROOT / ".dockerignore"
    findings += dockerfile_findings(
        (DEPLOY / "Dockerfile").read_text(), dockerignore.read_text() if dockerignore.exists() else ""
    )
    return findings, checked


def main() -> int:
    try:
        findings, checked = all_findings()
    except DeployCheckError as e:
        print(f"validate_deploy: {e}", file=sys.stderr)
        return 1
    for line in checked:
        print(f"validate_deploy: {line}")
    for finding in findings:
        print(f"validate_deploy: FINDING {finding}", file=sys.stderr)
    if findings:
        print(f"validate_deploy: {len(findings)} finding(s)", file=sys.stderr)
        return 1
    print("validate_deploy: every overlay passes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
