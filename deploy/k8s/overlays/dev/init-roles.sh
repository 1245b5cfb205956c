#!/bin/sh
# Run once by the postgres image on an empty data directory. Two roles, as in production: the schema
# owner (the migration Job: DDL) and the coordinator's role (DML on the owner's tables, nothing else).
# MAINTAIN (PostgreSQL 17+) lets the coordinator ANALYZE the tables it fills (Store::refresh_statistics).
set -eu
psql -v ON_ERROR_STOP=1 --username "$POSTGRES_USER" --dbname postgres \
    -v migrate_password="$VINT_MIGRATE_PASSWORD" -v app_password="$VINT_APP_PASSWORD" <<'SQL'
CREATE ROLE vint_migrate LOGIN PASSWORD :'migrate_password';
CREATE ROLE vint_app LOGIN PASSWORD :'app_password';
CREATE DATABASE vint OWNER vint_migrate;
\connect vint
GRANT USAGE ON SCHEMA public TO vint_app;
ALTER DEFAULT PRIVILEGES FOR ROLE vint_migrate IN SCHEMA public
    GRANT SELECT, INSERT, UPDATE, DELETE, MAINTAIN ON TABLES TO vint_app;
ALTER DEFAULT PRIVILEGES FOR ROLE vint_migrate IN SCHEMA public
    GRANT USAGE, SELECT, UPDATE ON SEQUENCES TO vint_app;
SQL
