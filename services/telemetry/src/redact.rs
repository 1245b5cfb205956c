//! Credentials out of what a process prints: every database or object-store URL that reaches a
//! log line, an error or stdout goes through `redact_url` first.

/// What a secret is replaced with.
pub const REDACTED: &str = "***";

/// `url` with its password (`scheme://user:PASSWORD@host`) and the values of its query
/// parameters that name one (`password=`, `sslpassword=`, …) replaced by `***`. Anything that is
/// not a URL comes back unchanged, so every URL-like string can go through it.
pub fn redact_url(url: &str) -> String {
    let (before_query, query) = match url.split_once('?') {
        Some((head, query)) => (head, Some(query)),
        None => (url, None),
    };
    let mut out = redact_userinfo(before_query);
    if let Some(query) = query {
        out.push('?');
        out.push_str(&redact_query(query));
    }
    out
}

/// `scheme://user:password@rest` → `scheme://user:***@rest`.
fn redact_userinfo(url: &str) -> String {
    let Some((scheme, rest)) = url.split_once("://") else {
        return url.to_string();
    };
    // The authority ends at the first '/' (or '#'); the userinfo at its last '@'.
    let authority_end = rest.find(['/', '#']).unwrap_or(rest.len());
    let (authority, path) = rest.split_at(authority_end);
    let Some((userinfo, host)) = authority.rsplit_once('@') else {
        return url.to_string();
    };
    match userinfo.split_once(':') {
        Some((user, _password)) => format!("{scheme}://{user}:{REDACTED}@{host}{path}"),
        None => url.to_string(),
    }
}

/// `a=1&password=x` → `a=1&password=***`, for every parameter whose name ends in "password".
fn redact_query(query: &str) -> String {
    query
        .split('&')
        .map(|pair| match pair.split_once('=') {
            Some((name, _)) if name.to_ascii_lowercase().ends_with("password") => format!("{name}={REDACTED}"),
            _ => pair.to_string(),
        })
        .collect::<Vec<_>>()
        .join("&")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_password_in_the_userinfo_is_replaced() {
        assert_eq!(
            redact_url("postgres://vint:s3cr%40t@db.example:5432/vint?sslmode=require"),
            "postgres://vint:***@db.example:5432/vint?sslmode=require"
        );
        // An '@' inside the password (unescaped) still ends at the host's '@'.
        assert_eq!(redact_url("postgres://u:p@ss@h/db"), "postgres://u:***@h/db");
        assert_eq!(redact_url("s3://AKIA:secret@bucket/prefix"), "s3://AKIA:***@bucket/prefix");
    }

    #[test]
    fn password_query_parameters_are_replaced() {
        assert_eq!(
            redact_url("postgres://h/db?user=vint&password=hunter2&sslmode=verify-full&sslpassword=k"),
            "postgres://h/db?user=vint&password=***&sslmode=verify-full&sslpassword=***"
        );
        assert_eq!(redact_url("postgres://h/db?PASSWORD=x"), "postgres://h/db?PASSWORD=***");
    }

    #[test]
    fn urls_without_secrets_are_unchanged() {
        for url in [
            "postgres://postgres@127.0.0.1:5432/postgres",
            "postgres://127.0.0.1/db?sslmode=prefer",
            "sqlite:///tmp/vint.db?mode=rwc",
            "sqlite:relative.db",
            "file:///data/objects",
            "s3://bucket/a@b/prefix",
            "not a url",
            "",
        ] {
            assert_eq!(redact_url(url), url);
        }
    }
}
