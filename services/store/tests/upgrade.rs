//! A database written before migration 0013 (a row a file in `artifacts`, a row a sample in
//! `samples`) opens with every file packed into `outputs`, its samples and lineage as they were,
//! and the old tables gone; on both dialects.

mod common;

use vint_store::Store;

const PACKAGE: &str = "j/package/can/trx3/c00000";
const RENDER: &str = "j/render/can/trx3/g000000";
const SAMPLE: &str = "can.trx3.g000000.v00";

/// Applies the migrations before 0013 to the database at `url`, as a release of then would have.
async fn migrate_to_0012(url: &str, postgres: bool) {
    sqlx::any::install_default_drivers();
    let mut migrator =
        if postgres { sqlx::migrate!("migrations/postgres") } else { sqlx::migrate!("migrations/sqlite") };
    let before: Vec<_> = migrator.migrations.iter().filter(|m| m.version < 13).cloned().collect();
    assert_eq!(before.len(), 12);
    migrator.migrations = before.into();
    let url = if postgres { url.to_string() } else { format!("{url}?mode=rwc") };
    let pool = sqlx::any::AnyPoolOptions::new().max_connections(1).connect(&url).await.unwrap();
    migrator.run(&pool).await.unwrap();
    let sha = |c: char| std::iter::repeat_n(c, 64).collect::<String>();
    let key = |c: char| vint_artifacts::key_for(&sha(c)).unwrap();
    let mut statements = vec![
        "INSERT INTO jobs (id, name, seed, spec_toml, idempotency_key, state, created_ms) \
         VALUES ('j', 'j', 1, '', 'k', 'succeeded', 0)"
            .to_string(),
    ];
    for (id, stage) in [(RENDER, "render"), (PACKAGE, "package")] {
        statements.push(format!(
            "INSERT INTO tasks (id, job_id, key, stage, priority, params_json, state, deps_pending, max_attempts, \
             created_ms, updated_ms) VALUES ('{id}', 'j', '{}', '{stage}', 0, '{{}}', 'succeeded', 0, 3, 0, 0)",
            id.strip_prefix("j/").unwrap()
        ));
    }
    statements.push(format!("INSERT INTO task_deps (task_id, depends_on) VALUES ('{PACKAGE}', '{RENDER}')"));
    for (task, name, c, size) in [
        (RENDER, "v00_rgb.png".to_string(), 'a', 1_000),
        (PACKAGE, format!("{SAMPLE}/rgb.png"), 'a', 1_000),
        (PACKAGE, format!("{SAMPLE}/meta.json"), 'b', 20),
        (PACKAGE, "can.trx3.g000000/grasp.json".to_string(), 'c', 30),
    ] {
        statements.push(format!(
            "INSERT INTO artifacts (task_id, name, sha256, size, media_type, object_key, created_ms) \
             VALUES ('{task}', '{name}', '{}', {size}, 'm', '{}', 0)",
            sha(c),
            key(c)
        ));
    }
    statements.push(format!(
        "INSERT INTO samples (job_id, sample_id, package_task_id) VALUES ('j', '{SAMPLE}', '{PACKAGE}')"
    ));
    for sql in statements {
        sqlx::query(sqlx::AssertSqlSafe(sql)).execute(&pool).await.unwrap();
    }
    pool.close().await;
}

async fn opens_packed(url: &str) {
    let store = Store::open(url, common::RETRY).await.unwrap();
    let files = store.artifacts_of_task(PACKAGE).await.unwrap();
    let names: Vec<&str> = files.iter().map(|a| a.name.as_str()).collect();
    assert_eq!(
        names,
        ["can.trx3.g000000.v00/meta.json", "can.trx3.g000000.v00/rgb.png", "can.trx3.g000000/grasp.json"]
    );
    assert!(files.iter().all(|a| a.object_key == vint_artifacts::key_for(&a.sha256).unwrap() && a.media_type == "m"));
    assert_eq!(files[1].size, 1_000);
    let samples = store.samples("j").await.unwrap();
    assert_eq!(samples.keys().collect::<Vec<_>>(), [SAMPLE]);
    assert_eq!(store.progress("j").await.unwrap().samples, 1);
    assert_eq!(store.sample_package_task(None, SAMPLE).await.unwrap(), Some(("j".into(), PACKAGE.into())));
    let chain = store.lineage(PACKAGE).await.unwrap();
    assert_eq!(chain[0].inputs.iter().map(|a| a.name.as_str()).collect::<Vec<_>>(), ["v00_rgb.png"]);
    let rows = store.table_rows().await.unwrap();
    assert_eq!((rows.outputs, rows.output_files), (2, 4));
    for table in ["artifacts", "samples"] {
        let gone = sqlx::query(sqlx::AssertSqlSafe(format!("SELECT COUNT(*) FROM {table}")));
        let pool = sqlx::any::AnyPoolOptions::new().max_connections(1).connect(url).await.unwrap();
        assert!(gone.fetch_one(&pool).await.is_err(), "{table} is dropped");
    }
    // Opening again finds nothing left to pack.
    drop(store);
    let again = Store::open(url, common::RETRY).await.unwrap();
    assert_eq!(again.artifacts_of_task(PACKAGE).await.unwrap(), files);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_sqlite_database_of_migration_0012_opens_with_its_outputs_packed() {
    let dir = tempfile::tempdir().unwrap();
    let url = format!("sqlite://{}", dir.path().join("vint.db").display());
    migrate_to_0012(&url, false).await;
    opens_packed(&url).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_postgres_database_of_migration_0012_opens_with_its_outputs_packed() {
    let url = common::empty_postgres_database().await;
    migrate_to_0012(&url, true).await;
    opens_packed(&url).await;
}
