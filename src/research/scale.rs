//! `eyekey bench --section scale`: eyekey on PostgreSQL with two API processes and 1, 2 and 4 worker
//! processes, all started from this binary on this machine: jobs per minute, claim latency (a job queued
//! while the workers are idle, to its claim), and the latency of job status reads spread over the two API
//! processes while the workers are busy. Not a test: nothing here asserts on time.
//!
//! The database is `--database-url`, or a throwaway server that `tests/postgres/server.sh` starts (and
//! stops when this process ends). Every worker count gets a database of its own.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{bail, Context as _, Result};
use serde_json::{json, Value};
use sqlx::Connection as _;

/// The operator token every process of the benchmark shares.
const TOKEN: &str = "bench-operator-token";
/// The master key every process of the benchmark shares.
const MASTER_KEY: &str = "5e2b9c0d8a7f6e5d4c3b2a1908f7e6d5c4b3a2918f7e6d5c4b3a29180f7e6d5c";
/// Jobs submitted at once for the throughput figure.
const JOBS: usize = 24;
/// Single jobs queued to idle workers for the claim-latency figure.
const CLAIMS: usize = 20;
/// Status reads for the latency figure.
const STATUS_READS: usize = 2000;

/// A process of the benchmark, killed when dropped.
struct Proc(Child, PathBuf);

impl Drop for Proc {
    fn drop(&mut self) {
        // SAFETY: kill(2) on our own child's pid: SIGTERM first, so workers re-queue what they hold.
        unsafe { libc::kill(self.0.id() as i32, libc::SIGTERM) };
        let deadline = Instant::now() + Duration::from_secs(30);
        while Instant::now() < deadline {
            if let Ok(Some(_)) = self.0.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn spawn(dir: &Path, name: &str, args: &[&str]) -> Result<Proc> {
    let data = dir.join(name);
    std::fs::create_dir_all(&data)?;
    let log = dir.join(format!("{name}.log"));
    let out = std::fs::File::create(&log)?;
    let child = Command::new(std::env::current_exe()?)
        .args(args)
        .arg("--data-dir")
        .arg(&data)
        .env("EYEKEY_MASTER_KEY", MASTER_KEY)
        .env("EYEKEY_OPERATOR_TOKEN", TOKEN)
        .env("RUST_LOG", "warn")
        .stdout(out.try_clone()?)
        .stderr(out)
        .spawn()?;
    Ok(Proc(child, log))
}

/// Waits for `serve`'s banner; returns its base URL.
async fn address_of(p: &Proc) -> Result<String> {
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let log = std::fs::read_to_string(&p.1).unwrap_or_default();
        if let Some(rest) = log.split("eyekey serving on ").nth(1) {
            return Ok(rest.split_whitespace().next().unwrap_or_default().to_string());
        }
        if Instant::now() > deadline {
            bail!("an API process did not start:\n{log}");
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

/// The URL of a PostgreSQL server's `postgres` database: the one given, or a throwaway server that
/// `tests/postgres/server.sh` starts on 127.0.0.1 and a free port (installing Debian's package if missing,
/// as root) and stops once this process has ended. The tests use it too.
pub fn postgres_server(given: Option<&str>) -> Result<String> {
    if let Some(url) = given {
        return Ok(url.to_string());
    }
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/postgres/server.sh");
    let dir = std::env::temp_dir().join(format!("eyekey-bench-pg-{}", std::process::id()));
    let out = Command::new("bash")
        .arg(&script)
        .arg("start")
        .arg(&dir)
        .arg(std::process::id().to_string())
        .stderr(Stdio::inherit())
        .output()
        .with_context(|| format!("running {}", script.display()))?;
    if !out.status.success() {
        bail!("{} could not start PostgreSQL", script.display());
    }
    Ok(String::from_utf8(out.stdout)?.trim().to_string())
}

/// Creates a new, empty database on the server whose administrative URL is `admin`; returns its URL.
pub async fn fresh_database(admin: &str) -> Result<String> {
    let name = format!("eyekey_bench_{}", uuid::Uuid::new_v4().simple());
    let mut conn = sqlx::PgConnection::connect(admin).await?;
    sqlx::query(&format!("CREATE DATABASE {name}"))
        .execute(&mut conn)
        .await?;
    let base = admin.rsplit_once('/').map_or(admin, |(b, _)| b);
    Ok(format!("{base}/{name}"))
}

/// One worker count's figures.
struct Figures {
    workers: usize,
    jobs_per_minute: f64,
    mean_solve_s: f64,
    claim_p50_ms: f64,
    claim_p99_ms: f64,
    status_p50_ms: f64,
    status_p99_ms: f64,
    status_rps: f64,
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

async fn post(client: &reqwest::Client, url: String, body: &Value) -> Result<Value> {
    let r = client.post(url).bearer_auth(TOKEN).json(body).send().await?;
    let status = r.status();
    let v: Value = r.json().await?;
    if !status.is_success() {
        bail!("{status}: {v}");
    }
    Ok(v)
}

/// Creates a job from `body` through the API process at `base`; returns its id.
async fn submit(client: &reqwest::Client, base: &str, body: &Value) -> Result<String> {
    let job = post(client, format!("{base}/v1/jobs"), body).await?;
    Ok(job["id"].as_str().unwrap_or_default().to_string())
}

/// The job every run submits: the `small` preset, a 48×48 document, a sampled target, options that keep
/// a job to about a second (geometric optics, 40 iterations, one decoy, no population evaluation).
async fn job_body(client: &reqwest::Client, base: &str) -> Result<Value> {
    let target = eyekey_core::physics::population::sample_population(1, 11, Default::default()).remove(0);
    let profile = post(
        client,
        format!("{base}/v1/profiles"),
        &json!({"label": "bench", "profile": target}),
    )
    .await?;
    let display = post(
        client,
        format!("{base}/v1/displays"),
        &json!({"name": "bench", "preset": "small"}),
    )
    .await?;
    let doc = post(
        client,
        format!("{base}/v1/documents/text"),
        &json!({"lines": ["PIN", "4821"], "width": 48, "height": 48, "scale": 1}),
    )
    .await?;
    Ok(json!({
        "display_id": display["display"]["id"],
        "document_id": doc["id"],
        "profile_id": profile["id"],
        "options": {"optics": "geometric", "max_iterations": 40, "population_decoys": 1, "near_pupil_decoys": 0,
                    "evaluation_population": 0, "sub_rays": 4},
    }))
}

async fn wait_all(client: &reqwest::Client, base: &str, ids: &[String]) -> Result<()> {
    for id in ids {
        loop {
            let v: Value = client
                .get(format!("{base}/v1/jobs/{id}"))
                .bearer_auth(TOKEN)
                .send()
                .await?
                .json()
                .await?;
            match v["state"].as_str() {
                Some("succeeded") => break,
                Some("failed" | "cancelled") => bail!("a benchmark job ended {}: {v}", v["state"]),
                _ => tokio::time::sleep(Duration::from_millis(50)).await,
            }
        }
    }
    Ok(())
}

async fn measure(admin: &str, workers: usize) -> Result<Figures> {
    let url = fresh_database(admin).await?;
    let dir = tempfile::tempdir()?;
    let api_args = [
        "serve",
        "--database-url",
        url.as_str(),
        "--bind",
        "127.0.0.1:0",
        "--workers",
        "0",
    ];
    let apis = [
        spawn(dir.path(), "api-1", &api_args)?,
        spawn(dir.path(), "api-2", &api_args)?,
    ];
    let bases = [address_of(&apis[0]).await?, address_of(&apis[1]).await?];
    let mut procs = Vec::new();
    for n in 0..workers {
        procs.push(spawn(
            dir.path(),
            &format!("worker-{n}"),
            &["worker", "--database-url", &url],
        )?);
    }
    let client = reqwest::Client::builder().timeout(Duration::from_secs(120)).build()?;
    let body = job_body(&client, &bases[0]).await?;
    // Warm-up: one job per worker, so every worker has connected and built its operators once.
    let mut warm = Vec::new();
    for _ in 0..workers {
        warm.push(submit(&client, &bases[0], &body).await?);
    }
    wait_all(&client, &bases[1], &warm).await?;

    // Claim latency: one job at a time to idle workers, from its creation to its claim (database times).
    let mut conn = sqlx::PgConnection::connect(&url).await?;
    let mut claims = Vec::new();
    for n in 0..CLAIMS {
        let id = submit(&client, &bases[n % 2], &body).await?;
        wait_all(&client, &bases[(n + 1) % 2], std::slice::from_ref(&id)).await?;
        let (created, started): (i64, i64) = sqlx::query_as("SELECT created_at, started_at FROM jobs WHERE id = $1")
            .bind(&id)
            .fetch_one(&mut conn)
            .await?;
        claims.push((started - created) as f64);
    }
    claims.sort_by(f64::total_cmp);

    // Throughput, with status reads through both API processes meanwhile.
    let started = Instant::now();
    let mut ids = Vec::new();
    for n in 0..JOBS {
        ids.push(submit(&client, &bases[n % 2], &body).await?);
    }
    // 8 clients, each reading its share of the statuses, alternating between the two API processes.
    let reads_started = Instant::now();
    let per_client = STATUS_READS / 8;
    let readers: Vec<_> = (0..8)
        .map(|c| {
            let (client, bases, ids) = (client.clone(), bases.clone(), ids.clone());
            tokio::spawn(async move {
                let mut lat = Vec::with_capacity(per_client);
                for k in c * per_client..(c + 1) * per_client {
                    let url = format!("{}/v1/jobs/{}", bases[k % 2], ids[k % ids.len()]);
                    let t = Instant::now();
                    let ok = client
                        .get(url)
                        .bearer_auth(TOKEN)
                        .send()
                        .await
                        .is_ok_and(|r| r.status().is_success());
                    if ok {
                        lat.push(t.elapsed().as_secs_f64() * 1e3);
                    }
                }
                (lat, reads_started.elapsed().as_secs_f64())
            })
        })
        .collect();
    wait_all(&client, &bases[1], &ids).await?;
    let elapsed = started.elapsed().as_secs_f64();
    // The reads' rate is over the span until the last client finished.
    let (mut lat, mut read_secs) = (Vec::with_capacity(STATUS_READS), 0f64);
    for reader in readers {
        let (l, secs) = reader.await?;
        lat.extend(l);
        read_secs = read_secs.max(secs);
    }
    lat.sort_by(f64::total_cmp);
    let (solve_ms,): (f64,) = sqlx::query_as("SELECT AVG(solve_ms)::float8 FROM jobs WHERE id = ANY($1)")
        .bind(&ids)
        .fetch_one(&mut conn)
        .await?;
    drop(procs);
    drop(apis);
    Ok(Figures {
        workers,
        jobs_per_minute: JOBS as f64 / elapsed * 60.0,
        mean_solve_s: solve_ms / 1e3,
        claim_p50_ms: percentile(&claims, 0.5),
        claim_p99_ms: percentile(&claims, 0.99),
        status_p50_ms: percentile(&lat, 0.5),
        status_p99_ms: percentile(&lat, 0.99),
        status_rps: lat.len() as f64 / read_secs,
    })
}

/// Runs the section; returns its Markdown.
pub fn run(database_url: Option<&str>, stamp: &str) -> Result<String> {
    let admin = postgres_server(database_url)?;
    let rt = tokio::runtime::Builder::new_multi_thread().enable_all().build()?;
    let mut rows = Vec::new();
    for workers in [1, 2, 4] {
        let f = rt.block_on(measure(&admin, workers))?;
        eprintln!(
            "scale: {workers} worker(s): {:.1} jobs/min, claim p50 {:.0} ms",
            f.jobs_per_minute, f.claim_p50_ms
        );
        rows.push(f);
    }
    let base = rows[0].jobs_per_minute;
    let mut md = format!(
        "Measured {stamp} by `eyekey bench --section scale` ({} build, {} cores): PostgreSQL 15 on loopback, two \
         `eyekey serve --workers 0` processes and N `eyekey worker` processes on this one machine. Each row: \
         {JOBS} jobs submitted at once through both API processes (the `small` preset, a 48×48 PIN slip, \
         geometric optics, 40 iterations, one decoy, no population evaluation), after one warm-up job per worker; \
         claim latency over {CLAIMS} jobs queued one at a time to idle workers (`started_at − created_at`); \
         {STATUS_READS} `GET /v1/jobs/{{id}}` from 8 concurrent clients alternating between the two API processes \
         while the {JOBS} jobs run.\n\n\
         | workers | jobs/min | × 1 worker | mean solve (s) | claim p50 (ms) | claim p99 (ms) | status p50 (ms) | status p99 (ms) | status reads/s |\n\
         |---|---|---|---|---|---|---|---|---|\n",
        if cfg!(debug_assertions) { "debug" } else { "release" },
        std::thread::available_parallelism().map_or(0, |n| n.get()),
    );
    for f in &rows {
        md.push_str(&format!(
            "| {} | {:.1} | {:.2} | {:.2} | {:.0} | {:.0} | {:.1} | {:.1} | {:.0} |\n",
            f.workers,
            f.jobs_per_minute,
            f.jobs_per_minute / base,
            f.mean_solve_s,
            f.claim_p50_ms,
            f.claim_p99_ms,
            f.status_p50_ms,
            f.status_p99_ms,
            f.status_rps
        ));
    }
    md.push('\n');
    Ok(md)
}
