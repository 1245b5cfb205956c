//! Who may call what: the coordinator's bearer tokens (`--auth-tokens FILE`), the one table that
//! maps every RPC to the roles allowed to call it, and the tower layer that enforces both in front
//! of `JobService` and `WorkService`.
//!
//! A token has one role: `submit` (submit and cancel jobs, and everything `read` may do: a
//! submitter watches the jobs it submits), `worker` (lease, heartbeat, complete and fail tasks;
//! nothing of `JobService`), `read` (jobs, progress, lineage, samples, server info). An RPC missing
//! from `RPC_ROLES` is refused to every token, so a new RPC cannot be left open by mistake; the
//! only calls taken without a token are those of `PUBLIC_RPCS` (the gRPC health check).
//!
//! A token also has a name (`ROLE TOKEN NAME`; without one, `token-` and the first 12 hex digits
//! of its SHA-256): the identity a call acts as. The worker API acts for the worker id a call
//! claims *under its token's name* (`NAME/ID`), so the holder of one worker token cannot
//! heartbeat, complete, fail or release the leases of a worker holding another; give each pool
//! (or each worker) its own token. Tokens sharing a name share an identity (rotating a pool's
//! token keeps its leases).
//!
//! Tokens are kept as SHA-256 digests and compared in constant time; no token is ever logged or
//! repeated in an error. Without a tokens file nothing is checked (the coordinator then listens on
//! loopback only, which the binary enforces).

use std::collections::HashMap;
use std::fmt;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::task::{Context, Poll};

use futures::future::{Either, Ready, ready};
use sha2::{Digest, Sha256};
use subtle::ConstantTimeEq;

/// What a token may do.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Role {
    /// Submit and cancel jobs; implies `Read`.
    Submit,
    /// Lease and report tasks (`WorkService`).
    Worker,
    /// Read jobs, progress, lineage, samples and server info.
    Read,
}

impl Role {
    pub const ALL: [Role; 3] = [Role::Submit, Role::Worker, Role::Read];

    pub fn name(self) -> &'static str {
        match self {
            Role::Submit => "submit",
            Role::Worker => "worker",
            Role::Read => "read",
        }
    }

    /// Whether a token of this role may do what `needed` allows.
    pub fn grants(self, needed: Role) -> bool {
        self == needed || (self == Role::Submit && needed == Role::Read)
    }
}

impl fmt::Display for Role {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Role {
    type Err = ();
    fn from_str(s: &str) -> Result<Role, ()> {
        Role::ALL.into_iter().find(|r| r.name() == s).ok_or(())
    }
}

/// Every RPC of both services (gRPC path) and the role it needs. `Role::grants` adds the
/// implication (a `submit` token may call what `read` may).
pub const RPC_ROLES: &[(&str, Role)] = &[
    ("/vint.v1.JobService/SubmitJob", Role::Submit),
    ("/vint.v1.JobService/CancelJob", Role::Submit),
    ("/vint.v1.JobService/GetJob", Role::Read),
    ("/vint.v1.JobService/ListJobs", Role::Read),
    ("/vint.v1.JobService/WatchJob", Role::Read),
    ("/vint.v1.JobService/GetLineage", Role::Read),
    ("/vint.v1.JobService/ListSamples", Role::Read),
    ("/vint.v1.JobService/GetServerInfo", Role::Read),
    ("/vint.v1.JobService/QueryDashboard", Role::Read),
    ("/vint.v1.WorkService/LeaseTasks", Role::Worker),
    ("/vint.v1.WorkService/Heartbeat", Role::Worker),
    ("/vint.v1.WorkService/CompleteTask", Role::Worker),
    ("/vint.v1.WorkService/CompleteTasks", Role::Worker),
    ("/vint.v1.WorkService/ReleaseTasks", Role::Worker),
    ("/vint.v1.WorkService/FailTask", Role::Worker),
];

/// RPCs answered without a token: the standard gRPC health check, which orchestrators probe
/// without credentials and which tells nothing but whether the coordinator serves.
pub const PUBLIC_RPCS: &[&str] = &["/grpc.health.v1.Health/Check", "/grpc.health.v1.Health/Watch"];

/// The role an RPC needs; `None` for a path not in `RPC_ROLES` (refused to everyone).
pub fn rpc_role(path: &str) -> Option<Role> {
    RPC_ROLES.iter().find(|(p, _)| *p == path).map(|&(_, role)| role)
}

/// Shortest token accepted: a guessable token is no token.
pub const MIN_TOKEN_LEN: usize = 16;

/// Longest token name.
pub const MAX_NAME_LEN: usize = 64;

/// Who a call comes from: its token's role and name. The auth layer puts it in the request's
/// extensions; without a tokens file there is none.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Caller {
    pub role: Role,
    pub name: Arc<str>,
}

/// Whether `name` is a token name: 1 to 64 of `[a-z0-9_-]`.
fn valid_name(name: &str) -> bool {
    !name.is_empty()
        && name.len() <= MAX_NAME_LEN
        && name.bytes().all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'_' || b == b'-')
}

/// A tokens file that cannot be used. The messages name the file and line, never a token.
#[derive(Debug, thiserror::Error)]
pub enum TokensFileError {
    #[error("--auth-tokens {}: cannot read it: {source}", path.display())]
    Read { path: PathBuf, source: std::io::Error },
    #[error("--auth-tokens {}, line {line}: {rule}", path.display())]
    Line { path: PathBuf, line: usize, rule: String },
    #[error("--auth-tokens {}: no tokens in it (one line per token: ROLE TOKEN [NAME], ROLE one of submit, worker, read)", path.display())]
    Empty { path: PathBuf },
}

/// Why a call is refused.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Denied {
    /// No token, a malformed `authorization` header, or a token not in the file.
    Unauthenticated(String),
    /// A known token whose role does not allow the call.
    PermissionDenied(String),
}

impl Denied {
    pub fn into_status(self) -> tonic::Status {
        match self {
            Denied::Unauthenticated(m) => tonic::Status::unauthenticated(m),
            Denied::PermissionDenied(m) => tonic::Status::permission_denied(m),
        }
    }
}

/// The tokens of a tokens file, as digests with their callers.
pub struct Tokens {
    digests: Vec<([u8; 32], Caller)>,
}

impl fmt::Debug for Tokens {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Tokens").field("count", &self.digests.len()).finish_non_exhaustive()
    }
}

fn digest(token: &[u8]) -> [u8; 32] {
    Sha256::digest(token).into()
}

impl Tokens {
    /// Reads and parses a tokens file (see `parse`).
    pub fn load(path: &Path) -> Result<Tokens, TokensFileError> {
        let text = std::fs::read_to_string(path)
            .map_err(|source| TokensFileError::Read { path: path.to_path_buf(), source })?;
        Tokens::parse(&text, path)
    }

    /// Parses the text of a tokens file: one `ROLE TOKEN [NAME]` per line, blank lines and `#`
    /// comments allowed. A line that is not two or three fields, an unknown role, a short token, a
    /// token with characters outside printable ASCII, a bad name, a token listed twice, or no
    /// token at all is an error.
    pub fn parse(text: &str, path: &Path) -> Result<Tokens, TokensFileError> {
        let mut digests = Vec::new();
        let mut seen: HashMap<[u8; 32], usize> = HashMap::new();
        for (i, line) in text.lines().enumerate() {
            let n = i + 1;
            let bad = |rule: String| TokensFileError::Line { path: path.to_path_buf(), line: n, rule };
            let line = line.trim();
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            let fields: Vec<&str> = line.split_whitespace().collect();
            let (role, token, name) = match fields[..] {
                [role, token] => (role, token, None),
                [role, token, name] => (role, token, Some(name)),
                _ => {
                    return Err(bad(format!(
                        "expected two or three fields, ROLE TOKEN [NAME], got {} (the line is not repeated here: \
                         it may hold a token)",
                        fields.len()
                    )));
                }
            };
            let role: Role = role.parse().map_err(|()| {
                bad("the first field must be a role: submit, worker or read (the value is not repeated here: \
                     it may be a token)"
                    .to_string())
            })?;
            if token.len() < MIN_TOKEN_LEN {
                return Err(bad(format!("the token must be at least {MIN_TOKEN_LEN} characters, got {}", token.len())));
            }
            if !token.bytes().all(|b| b.is_ascii_graphic()) {
                return Err(bad("the token must be printable ASCII without spaces".to_string()));
            }
            let d = digest(token.as_bytes());
            if let Some(first) = seen.insert(d, n) {
                return Err(bad(format!("the same token as line {first}: a token has one role")));
            }
            let name = match name {
                Some(name) if valid_name(name) => name.to_string(),
                Some(_) => {
                    return Err(bad(format!(
                        "the name (third field) must be 1 to {MAX_NAME_LEN} of a-z, 0-9, '_' and '-' (the value is \
                         not repeated here: it may be a token)"
                    )));
                }
                None => format!("token-{}", &hex::encode(d)[..12]),
            };
            digests.push((d, Caller { role, name: name.into() }));
        }
        if digests.is_empty() {
            return Err(TokensFileError::Empty { path: path.to_path_buf() });
        }
        Ok(Tokens { digests })
    }

    /// The caller `token` makes, comparing against every known token in constant time.
    fn caller_of(&self, token: &str) -> Option<&Caller> {
        let presented = digest(token.as_bytes());
        let mut found = None;
        for (d, caller) in &self.digests {
            if bool::from(d.ct_eq(&presented)) {
                found = Some(caller);
            }
        }
        found
    }

    /// Checks an `authorization` header (`Bearer TOKEN`) for a role that grants `needed`; returns
    /// the token's role. The HTTP server calls this for its `read` endpoints.
    pub fn authorize_bearer(&self, authorization: Option<&http::HeaderValue>, needed: Role) -> Result<Role, Denied> {
        let role = self.authenticate(authorization)?.role;
        if role.grants(needed) {
            Ok(role)
        } else {
            Err(Denied::PermissionDenied(format!("a {role} token may not do what needs the {needed} role")))
        }
    }

    /// Checks a gRPC call to `path`: the header's token and the role `RPC_ROLES` names for it;
    /// returns who calls.
    pub fn authorize_rpc(&self, path: &str, authorization: Option<&http::HeaderValue>) -> Result<Caller, Denied> {
        let caller = self.authenticate(authorization)?;
        let role = caller.role;
        match rpc_role(path) {
            Some(needed) if role.grants(needed) => Ok(caller),
            Some(needed) => {
                Err(Denied::PermissionDenied(format!("{path} needs a {needed} token, this is a {role} token")))
            }
            None => Err(Denied::PermissionDenied(format!("{path} is open to no role"))),
        }
    }

    fn authenticate(&self, authorization: Option<&http::HeaderValue>) -> Result<Caller, Denied> {
        let header = authorization.ok_or_else(|| {
            Denied::Unauthenticated(
                "no token: this coordinator needs `authorization: Bearer TOKEN` (vintctl and vint-worker: --token \
                 or VINT_TOKEN)"
                    .to_string(),
            )
        })?;
        let token = header
            .to_str()
            .ok()
            .and_then(|h| h.split_once(' '))
            .filter(|(scheme, _)| scheme.eq_ignore_ascii_case("bearer"))
            .map(|(_, token)| token.trim())
            .ok_or_else(|| Denied::Unauthenticated("the authorization header must be `Bearer TOKEN`".to_string()))?;
        self.caller_of(token).cloned().ok_or_else(|| Denied::Unauthenticated("unknown token".to_string()))
    }
}

/// The tower layer that checks every gRPC call against `Tokens`; with `None` it lets every call
/// through (no tokens file: a loopback-only coordinator).
#[derive(Clone, Debug, Default)]
pub struct AuthLayer {
    tokens: Option<Arc<Tokens>>,
}

impl AuthLayer {
    pub fn new(tokens: Option<Arc<Tokens>>) -> AuthLayer {
        AuthLayer { tokens }
    }
}

impl<S> tower::Layer<S> for AuthLayer {
    type Service = Authorized<S>;
    fn layer(&self, inner: S) -> Authorized<S> {
        Authorized { inner, tokens: self.tokens.clone() }
    }
}

/// A service behind `AuthLayer`: a refused call is answered with its gRPC status and never
/// reaches the service.
#[derive(Clone, Debug)]
pub struct Authorized<S> {
    inner: S,
    tokens: Option<Arc<Tokens>>,
}

impl<S, ReqBody, ResBody> tower::Service<http::Request<ReqBody>> for Authorized<S>
where
    S: tower::Service<http::Request<ReqBody>, Response = http::Response<ResBody>>,
    ResBody: Default,
{
    type Response = http::Response<ResBody>;
    type Error = S::Error;
    type Future = Either<Ready<Result<http::Response<ResBody>, S::Error>>, S::Future>;

    fn poll_ready(&mut self, cx: &mut Context<'_>) -> Poll<Result<(), S::Error>> {
        self.inner.poll_ready(cx)
    }

    fn call(&mut self, mut request: http::Request<ReqBody>) -> Self::Future {
        if let Some(tokens) = &self.tokens {
            let path = request.uri().path();
            if PUBLIC_RPCS.contains(&path) {
                return Either::Right(self.inner.call(request));
            }
            match tokens.authorize_rpc(path, request.headers().get(http::header::AUTHORIZATION)) {
                Ok(caller) => {
                    request.extensions_mut().insert(caller);
                }
                Err(denied) => {
                    tracing::info!(rpc = %path, ?denied, "call refused");
                    return Either::Left(ready(Ok(denied.into_status().into_http())));
                }
            }
        }
        Either::Right(self.inner.call(request))
    }
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeSet;

    use super::*;

    const SUBMIT: &str = "submit-token-0123456789";
    const WORKER: &str = "worker-token-0123456789";
    const READ: &str = "read-token-0123456789";

    fn parse(text: &str) -> Result<Tokens, TokensFileError> {
        Tokens::parse(text, Path::new("tokens.txt"))
    }

    fn line_error(text: &str) -> (usize, String) {
        match parse(text) {
            Err(TokensFileError::Line { line, rule, .. }) => (line, rule),
            other => panic!("expected a line error for {text:?}, got {other:?}"),
        }
    }

    fn bearer(token: &str) -> http::HeaderValue {
        http::HeaderValue::from_str(&format!("Bearer {token}")).unwrap()
    }

    fn three() -> Tokens {
        parse(&format!("# roles\n\nsubmit {SUBMIT}\n  worker\t{WORKER}  \nread {READ}\n")).unwrap()
    }

    #[test]
    fn a_tokens_file_with_comments_and_blank_lines_parses() {
        let tokens = three();
        let role_of = |token: &str| tokens.caller_of(token).map(|c| c.role);
        assert_eq!(role_of(SUBMIT), Some(Role::Submit));
        assert_eq!(role_of(WORKER), Some(Role::Worker));
        assert_eq!(role_of(READ), Some(Role::Read));
        assert_eq!(role_of("read-token-012345678"), None);
    }

    #[test]
    fn a_token_s_name_is_its_third_field_or_its_digest_s_start() {
        let tokens = parse(&format!("worker {WORKER} pool-a\nworker worker-token-9876543210\n")).unwrap();
        assert_eq!(&*tokens.caller_of(WORKER).unwrap().name, "pool-a");
        let unnamed = tokens.caller_of("worker-token-9876543210").unwrap();
        let expected = hex::encode(Sha256::digest(b"worker-token-9876543210"));
        assert_eq!(*unnamed.name, format!("token-{}", &expected[..12]));
        for bad in ["Pool", "a/b", "pool.a", &"x".repeat(65)] {
            let (_, rule) = line_error(&format!("worker {WORKER} {bad}\n"));
            assert!(rule.contains("the name (third field)") && !rule.contains(WORKER), "{bad}: {rule}");
        }
    }

    #[test]
    fn each_bad_line_names_its_line_and_rule_and_never_the_token() {
        let (line, rule) = line_error(&format!("# c\nsubmit {SUBMIT} name extra\n"));
        assert_eq!(line, 2);
        assert!(rule.contains("two or three fields") && rule.contains("got 4"), "{rule}");
        let (line, rule) = line_error(&format!("submit {SUBMIT}\nadmin {WORKER}\n"));
        assert_eq!(line, 2);
        assert!(rule.contains("submit, worker or read") && !rule.contains(WORKER), "{rule}");
        let (_, rule) = line_error(&format!("{READ} read\n"));
        assert!(!rule.contains(READ), "a token written in the role's place is not repeated: {rule}");
        let (_, rule) = line_error("read short\n");
        assert!(rule.contains("at least 16 characters"), "{rule}");
        let (_, rule) = line_error("read tökentökentökentöken\n");
        assert!(rule.contains("printable ASCII"), "{rule}");
        let (line, rule) = line_error(&format!("submit {SUBMIT}\n\nread {SUBMIT}\n"));
        assert_eq!(line, 3);
        assert!(rule.contains("line 1") && !rule.contains(SUBMIT), "{rule}");
        let message = parse(&format!("read {READ} x y\n")).unwrap_err().to_string();
        assert!(message.starts_with("--auth-tokens tokens.txt, line 1: "), "{message}");
    }

    #[test]
    fn an_empty_or_comment_only_file_is_an_error() {
        assert!(matches!(parse(""), Err(TokensFileError::Empty { .. })));
        assert!(matches!(parse("# nobody\n\n"), Err(TokensFileError::Empty { .. })));
        let missing = Tokens::load(Path::new("/nonexistent/tokens.txt")).unwrap_err();
        assert!(matches!(missing, TokensFileError::Read { .. }), "{missing}");
    }

    #[test]
    fn submit_implies_read_and_nothing_else_implies_anything() {
        for have in Role::ALL {
            for needed in Role::ALL {
                let expected = have == needed || (have, needed) == (Role::Submit, Role::Read);
                assert_eq!(have.grants(needed), expected, "{have} grants {needed}");
            }
        }
    }

    #[test]
    fn calls_without_a_known_token_are_unauthenticated_and_outside_the_role_denied() {
        let tokens = three();
        let submit = "/vint.v1.JobService/SubmitJob";
        let lease = "/vint.v1.WorkService/LeaseTasks";
        let get = "/vint.v1.JobService/GetJob";
        assert!(matches!(tokens.authorize_rpc(submit, None), Err(Denied::Unauthenticated(_))));
        let wrong = bearer("nobody-knows-this-token");
        assert!(matches!(tokens.authorize_rpc(submit, Some(&wrong)), Err(Denied::Unauthenticated(_))));
        let basic = http::HeaderValue::from_static("Basic dXNlcjpwYXNz");
        assert!(matches!(tokens.authorize_rpc(submit, Some(&basic)), Err(Denied::Unauthenticated(_))));
        let role = |path: &str, token: &str| tokens.authorize_rpc(path, Some(&bearer(token))).map(|c| c.role);
        assert_eq!(role(submit, SUBMIT), Ok(Role::Submit));
        assert_eq!(role(get, SUBMIT), Ok(Role::Submit));
        assert_eq!(role(lease, WORKER), Ok(Role::Worker));
        assert!(matches!(tokens.authorize_rpc(submit, Some(&bearer(WORKER))), Err(Denied::PermissionDenied(_))));
        assert!(matches!(tokens.authorize_rpc(lease, Some(&bearer(READ))), Err(Denied::PermissionDenied(_))));
        assert!(matches!(tokens.authorize_rpc(lease, Some(&bearer(SUBMIT))), Err(Denied::PermissionDenied(_))));
        let unknown = "/vint.v1.JobService/DeleteEverything";
        assert!(matches!(tokens.authorize_rpc(unknown, Some(&bearer(SUBMIT))), Err(Denied::PermissionDenied(_))));
        assert_eq!(tokens.authorize_bearer(Some(&bearer(READ)), Role::Read), Ok(Role::Read));
        assert!(matches!(tokens.authorize_bearer(Some(&bearer(WORKER)), Role::Read), Err(Denied::PermissionDenied(_))));
    }

    /// Every RPC the proto files declare is in `RPC_ROLES`, and the table names no other.
    #[test]
    fn the_role_table_covers_exactly_the_rpcs_of_the_proto_files() {
        let mut declared = BTreeSet::new();
        for proto in
            [include_str!("../../../proto/vint/v1/jobs.proto"), include_str!("../../../proto/vint/v1/work.proto")]
        {
            let package = proto
                .lines()
                .find_map(|l| l.trim().strip_prefix("package ")?.strip_suffix(';'))
                .expect("a package line");
            let mut service = None;
            for line in proto.lines().map(str::trim) {
                if let Some(rest) = line.strip_prefix("service ") {
                    service = rest.split_whitespace().next();
                } else if let Some(rest) = line.strip_prefix("rpc ") {
                    let method = rest.split('(').next().expect("rpc Name(").trim();
                    declared.insert(format!("/{package}.{}/{method}", service.expect("rpc inside a service")));
                }
            }
        }
        assert!(declared.len() >= 13, "parsed too few RPCs: {declared:?}");
        let table: BTreeSet<String> = RPC_ROLES.iter().map(|(p, _)| p.to_string()).collect();
        assert_eq!(table.len(), RPC_ROLES.len(), "an RPC is listed twice");
        let missing: Vec<_> = declared.difference(&table).collect();
        let extra: Vec<_> = table.difference(&declared).collect();
        assert!(missing.is_empty(), "RPCs with no role (every token is refused them): {missing:?}");
        assert!(extra.is_empty(), "RPCs in the role table the proto files do not declare: {extra:?}");
    }
}
