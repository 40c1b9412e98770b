//! The operator console in a real headless Chromium, driven over WebDriver (ChromeDriver): sign in, enrol
//! (form and JSON file), register a display, render and upload documents, create a job, watch it finish,
//! and check its page shows the side-by-side views. A wrong token shows an error and nothing else; the
//! browser's console holds no error. Screenshots of each page go to `target/tmp/console/`.
//!
//! Chromium and ChromeDriver come from Debian (`tests/console/install-chromium.sh`, which `.ci/run` runs and
//! this test runs itself when they are missing). The test fails, never skips, when they cannot be had.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use fantoccini::{Client, ClientBuilder, Locator};
use serde_json::{json, Value};

use crate::helpers::{document_png, fast_options, myope, spawn_app_with, tiny_display, OPERATOR_TOKEN};

/// ChromeDriver on a free loopback port, killed when dropped.
struct Driver {
    child: Child,
    url: String,
}

impl Drop for Driver {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn ensure_chromium() {
    let present = |name: &str| {
        Command::new("sh")
            .arg("-c")
            .arg(format!("command -v {name}"))
            .output()
            .is_ok_and(|o| o.status.success())
    };
    if present("chromedriver") && present("chromium") {
        return;
    }
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/console/install-chromium.sh");
    let run = Command::new("bash")
        .arg(&script)
        .status()
        .expect("bash runs the install script");
    assert!(
        run.success() && present("chromedriver"),
        "Chromium and ChromeDriver are needed for the console test: run {} as root",
        script.display()
    );
}

async fn start_driver() -> Driver {
    ensure_chromium();
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let child = Command::new("chromedriver")
        .arg(format!("--port={port}"))
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("chromedriver starts");
    let url = format!("http://127.0.0.1:{port}");
    let driver = Driver { child, url };
    for _ in 0..100 {
        if let Ok(r) = reqwest::get(format!("{}/status", driver.url)).await {
            let status: Value = r.json().await.unwrap_or_default();
            if status["value"]["ready"] == true {
                return driver;
            }
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    panic!("chromedriver did not become ready on port {port}");
}

async fn browser(driver: &Driver, profile_dir: &Path) -> Client {
    let caps = json!({
        "browserName": "chrome",
        "goog:chromeOptions": {
            "binary": "/usr/bin/chromium",
            "args": [
                "--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--disable-quic",
                "--no-first-run", "--disable-background-networking", "--disable-component-update", "--disable-sync",
                "--window-size=1280,1000", format!("--user-data-dir={}", profile_dir.display()),
            ],
        },
        "goog:loggingPrefs": { "browser": "ALL" },
    });
    let caps = caps.as_object().unwrap().clone().into_iter().collect();
    ClientBuilder::new(hyper_util::client::legacy::connect::HttpConnector::new())
        .capabilities(caps)
        .connect(&driver.url)
        .await
        .expect("a Chromium session")
}

/// ChromeDriver's browser log (console messages and failed loads since the last read).
#[derive(Debug)]
struct BrowserLog;

impl fantoccini::wd::WebDriverCompatibleCommand for BrowserLog {
    fn endpoint(&self, base: &url::Url, session: Option<&str>) -> Result<url::Url, url::ParseError> {
        base.join(&format!("session/{}/se/log", session.unwrap_or_default()))
    }
    fn method_and_body(&self, _: &url::Url) -> (http::Method, Option<String>) {
        (http::Method::POST, Some(r#"{"type":"browser"}"#.into()))
    }
}

async fn browser_errors(c: &Client) -> Vec<String> {
    let log = c.issue_cmd(BrowserLog).await.expect("the browser log");
    log.as_array()
        .unwrap_or(&Vec::new())
        .iter()
        .filter(|e| e["level"] == "SEVERE" || e["level"] == "WARNING")
        .map(|e| e["message"].as_str().unwrap_or_default().to_string())
        .collect()
}

/// After a request the test made fail on purpose: the browser logged that refusal and nothing else.
async fn expect_only_refusal(c: &Client, path: &str, status: u16) {
    let errors = browser_errors(c).await;
    assert!(!errors.is_empty(), "the browser logs the refused request to {path}");
    for e in errors {
        assert!(
            e.contains(path) && e.contains(&format!("status of {status}")),
            "unexpected browser error: {e}"
        );
    }
}

fn shots_dir() -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("console");
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Every input, select and textarea on the page has a label (or an aria-label), and there are some.
async fn assert_all_labelled(c: &Client, page: &str) {
    let counts = c
        .execute(
            "const all = [...document.querySelectorAll('input, select, textarea')]; \
             return [all.length, all.filter(e => !e.labels?.length && !e.getAttribute('aria-label')).map(e => e.outerHTML)];",
            vec![],
        )
        .await
        .unwrap();
    assert!(counts[0].as_u64().unwrap() > 0, "{page}: no inputs to check");
    assert_eq!(counts[1], json!([]), "{page}: inputs without a label");
}

async fn shot(c: &Client, name: &str) {
    c.execute("window.scrollTo(0, 0)", vec![]).await.unwrap();
    // Full page: grow the window to the document's height first.
    let height = c
        .execute("return Math.ceil(document.documentElement.scrollHeight)", vec![])
        .await
        .unwrap()
        .as_u64()
        .unwrap_or(1000)
        .clamp(600, 4000);
    c.set_window_size(1280, height as u32 + 120).await.unwrap();
    let png = c.screenshot().await.unwrap();
    std::fs::write(shots_dir().join(format!("{name}.png")), &png).unwrap();
    c.set_window_size(1280, 1000).await.unwrap();
}

/// Waits (up to `secs`) until the script returns true.
async fn wait_until(c: &Client, what: &str, script: &str, secs: u64) {
    let deadline = std::time::Instant::now() + Duration::from_secs(secs);
    loop {
        if c.execute(script, vec![]).await.unwrap() == Value::Bool(true) {
            return;
        }
        assert!(std::time::Instant::now() < deadline, "timed out waiting for {what}");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

/// Presses one key (a WebDriver key code such as Tab, U+E004) wherever the focus is.
async fn press(c: &Client, key: char) {
    use fantoccini::actions::{InputSource as _, KeyAction, KeyActions};
    let keys = KeyActions::new("keyboard".into())
        .then(KeyAction::Down { value: key })
        .then(KeyAction::Up { value: key });
    c.perform_actions(keys).await.unwrap();
}

async fn text_of(c: &Client, css: &str) -> String {
    c.find(Locator::Css(css)).await.unwrap().text().await.unwrap()
}

async fn type_into(c: &Client, css: &str, text: &str) {
    let el = c.find(Locator::Css(css)).await.unwrap_or_else(|e| panic!("{css}: {e}"));
    el.clear().await.unwrap();
    el.send_keys(text).await.unwrap();
}

async fn click(c: &Client, css: &str) {
    c.find(Locator::Css(css))
        .await
        .unwrap_or_else(|e| panic!("{css}: {e}"))
        .click()
        .await
        .unwrap();
}

async fn nav(c: &Client, page: &str) {
    click(c, &format!("#nav a[data-page={page}]")).await;
}

/// A form's input by its label's text.
async fn input_labelled(c: &Client, form: &str, label: &str) -> fantoccini::elements::Element {
    let id = c
        .execute(
            "const [form, text] = arguments; for (const l of document.querySelectorAll(form + ' label')) \
             { if (l.textContent.trim() === text) return l.htmlFor; } return null;",
            vec![json!(form), json!(label)],
        )
        .await
        .unwrap();
    let id = id
        .as_str()
        .unwrap_or_else(|| panic!("no label {label:?} in {form}"))
        .to_string();
    c.find(Locator::Id(&id)).await.unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_console_takes_an_operator_from_sign_in_to_a_finished_jobs_side_by_side_views() {
    let driver = start_driver().await;
    let app = spawn_app_with(|c| c.workers = 1).await;
    let files = tempfile::tempdir().unwrap();
    let chrome_profile = tempfile::tempdir().unwrap();
    let c = browser(&driver, chrome_profile.path()).await;

    // Sign-in page; a wrong token shows an error and nothing else.
    c.goto(&app.url("/console")).await.unwrap();
    c.wait().for_element(Locator::Css("#sign-in")).await.unwrap();
    shot(&c, "sign-in").await;
    assert_all_labelled(&c, "sign-in").await;
    type_into(&c, "#token", "eko_not-a-token").await;
    click(&c, "#sign-in button[type=submit]").await;
    wait_until(
        &c,
        "the sign-in error",
        "return document.querySelector('#sign-in .error').textContent !== ''",
        10,
    )
    .await;
    assert!(text_of(&c, "#sign-in .error")
        .await
        .contains("does not know this token"));
    assert_eq!(
        c.find(Locator::Css("#token"))
            .await
            .unwrap()
            .attr("aria-invalid")
            .await
            .unwrap()
            .as_deref(),
        Some("true")
    );
    let visible = c
        .execute("return [document.getElementById('nav').hidden, document.querySelectorAll('main table, main h2').length, sessionStorage.length]", vec![])
        .await
        .unwrap();
    assert_eq!(
        visible,
        json!([true, 0, 0]),
        "nothing but the error is shown, and nothing is kept"
    );
    expect_only_refusal(&c, "/v1/me", 401).await;

    // Keyboard only: the error put the focus on the field it names, Tab moves on to the button, and Enter in
    // the field signs in.
    let focused = c.execute("return document.activeElement.id", vec![]).await.unwrap();
    assert_eq!(focused, json!("token"), "the field in error has the focus");
    press(&c, '\u{E004}').await;
    let focused = c
        .execute("return document.activeElement.textContent", vec![])
        .await
        .unwrap();
    assert_eq!(focused, json!("Sign in"), "Tab reaches the button");
    type_into(&c, "#token", OPERATOR_TOKEN).await;
    c.find(Locator::Css("#token"))
        .await
        .unwrap()
        .send_keys("\u{E007}")
        .await
        .unwrap();
    wait_until(
        &c,
        "the jobs page",
        "return !document.getElementById('nav').hidden && document.querySelector('h1').textContent === 'Jobs'",
        10,
    )
    .await;
    assert!(text_of(&c, "#who-name").await.contains("operator (admin)"));
    let url = c.current_url().await.unwrap();
    assert!(
        !url.as_str().contains(OPERATOR_TOKEN),
        "the token never appears in a URL"
    );

    // Profiles: one from the form, one from a JSON file.
    nav(&c, "profiles").await;
    c.wait().for_element(Locator::Css("#enrol-form")).await.unwrap();
    input_labelled(&c, "#enrol-form", "Label")
        .await
        .send_keys("Ada")
        .await
        .unwrap();
    click(&c, "#enrol-form button[type=submit]").await;
    wait_until(
        &c,
        "Ada's enrolment",
        "return document.querySelector('#enrol-form .notice').textContent.includes('Enrolled Ada')",
        10,
    )
    .await;
    let profile_file = files.path().join("bob.json");
    std::fs::write(&profile_file, serde_json::to_vec(&myope()).unwrap()).unwrap();
    input_labelled(&c, "#enrol-file", "Label")
        .await
        .send_keys("Bob")
        .await
        .unwrap();
    input_labelled(&c, "#enrol-file", "Profile file")
        .await
        .send_keys(profile_file.to_str().unwrap())
        .await
        .unwrap();
    click(&c, "#enrol-file button[type=submit]").await;
    wait_until(
        &c,
        "Bob's enrolment",
        "return document.querySelector('#enrol-file .notice').textContent.includes('Enrolled Bob')",
        10,
    )
    .await;
    wait_until(
        &c,
        "two profiles listed",
        "return document.querySelectorAll('#profiles > tbody > tr:not([hidden])').length === 2",
        10,
    )
    .await;
    // Re-enrolment from Bob's versions panel makes version 2, and both versions can be read.
    let bob_row = "//table[@id='profiles']/tbody/tr[td[1][normalize-space()='Bob']]";
    c.find(Locator::XPath(&format!(
        "{bob_row}//button[normalize-space()='Versions']"
    )))
    .await
    .unwrap()
    .click()
    .await
    .unwrap();
    wait_until(
        &c,
        "Bob's profile",
        "return !!document.querySelector('#profiles pre')",
        10,
    )
    .await;
    let mut changed = myope();
    changed.pupil_diameter_mm = 4.0;
    std::fs::write(&profile_file, serde_json::to_vec(&changed).unwrap()).unwrap();
    c.find(Locator::XPath("//table[@id='profiles']//form//input[@type='file']"))
        .await
        .unwrap()
        .send_keys(profile_file.to_str().unwrap())
        .await
        .unwrap();
    c.find(Locator::XPath("//table[@id='profiles']//form//button[@type='submit']"))
        .await
        .unwrap()
        .click()
        .await
        .unwrap();
    wait_until(
        &c,
        "Bob's version 2",
        "return [...document.querySelectorAll('#profiles td.num')].some(td => td.textContent === '2')",
        10,
    )
    .await;
    shot(&c, "profiles").await;
    assert_all_labelled(&c, "profiles").await;

    // A bad value is answered in place, naming the field, and what was typed stays.
    let pupil = input_labelled(&c, "#enrol-form", "Pupil diameter while viewing, mm").await;
    pupil.clear().await.unwrap();
    pupil.send_keys("12").await.unwrap();
    click(&c, "#enrol-form button[type=submit]").await;
    wait_until(
        &c,
        "the enrolment error",
        "return document.querySelector('#enrol-form .error').textContent !== ''",
        10,
    )
    .await;
    assert!(text_of(&c, "#enrol-form .error")
        .await
        .contains("profile.pupil_diameter_mm"));
    assert_eq!(pupil.prop("value").await.unwrap().as_deref(), Some("12"));
    assert_eq!(pupil.attr("aria-invalid").await.unwrap().as_deref(), Some("true"));
    expect_only_refusal(&c, "/v1/profiles", 422).await;

    // Displays: a geometry as JSON; the token is shown once.
    nav(&c, "displays").await;
    c.wait().for_element(Locator::Css("#register-display")).await.unwrap();
    input_labelled(&c, "#register-display", "Name")
        .await
        .send_keys("Lobby")
        .await
        .unwrap();
    click(&c, "#register-display input[value=geometry]").await;
    let geometry = serde_json::to_string(&tiny_display()).unwrap();
    input_labelled(&c, "#register-display", "Geometry")
        .await
        .send_keys(&geometry)
        .await
        .unwrap();
    click(&c, "#register-display button[type=submit]").await;
    wait_until(
        &c,
        "the display token",
        "return document.querySelector('[data-token-panel] input') !== null",
        10,
    )
    .await;
    let token = c
        .find(Locator::Css("[data-token-panel] input"))
        .await
        .unwrap()
        .prop("value")
        .await
        .unwrap()
        .unwrap();
    assert!(token.starts_with("ekd_"), "{token}");
    let empty_cells = c
        .execute("return [...document.querySelectorAll('#display-token table.resolvability td')].filter(td => td.textContent.trim() === '').length", vec![])
        .await
        .unwrap();
    assert_eq!(empty_cells, json!(0), "every resolvability figure is shown");
    shot(&c, "displays").await;
    assert_all_labelled(&c, "displays").await;

    // Documents: a rendered PIN slip (the text that does not fit is refused in place first) and an upload
    // with a preview.
    nav(&c, "documents").await;
    c.wait().for_element(Locator::Css("#render-document")).await.unwrap();
    let scale = input_labelled(&c, "#render-document", "Pixels per font dot").await;
    scale.clear().await.unwrap();
    scale.send_keys("64").await.unwrap();
    click(&c, "#render-document button[type=submit]").await;
    wait_until(
        &c,
        "the render error",
        "return document.querySelector('#render-document .error').textContent !== ''",
        10,
    )
    .await;
    assert!(text_of(&c, "#render-document .error").await.contains("does not fit"));
    expect_only_refusal(&c, "/v1/documents/text", 422).await;
    for (label, value) in [("Pixels per font dot", "2"), ("Width, px", "48"), ("Height, px", "48")] {
        let el = input_labelled(&c, "#render-document", label).await;
        el.clear().await.unwrap();
        el.send_keys(value).await.unwrap();
    }
    click(&c, "#render-document button[type=submit]").await;
    wait_until(
        &c,
        "the rendered document",
        "const i = document.querySelector('#render-document img'); return !!i && i.complete && i.naturalWidth === 48",
        10,
    )
    .await;
    let png = files.path().join("slip.png");
    std::fs::write(&png, document_png(24, 24)).unwrap();
    input_labelled(&c, "#upload-document", "PNG or JPEG image")
        .await
        .send_keys(png.to_str().unwrap())
        .await
        .unwrap();
    wait_until(
        &c,
        "the upload preview",
        "const i = document.querySelector('#upload-document img'); return !!i && i.complete && i.naturalWidth === 24",
        10,
    )
    .await;
    click(&c, "#upload-document button[type=submit]").await;
    wait_until(
        &c,
        "the upload",
        "return document.querySelector('#upload-document .notice').textContent.includes('Stored')",
        10,
    )
    .await;
    wait_until(
        &c,
        "two documents listed",
        "return document.querySelectorAll('#documents tbody tr').length === 2",
        10,
    )
    .await;
    shot(&c, "documents").await;
    assert_all_labelled(&c, "documents").await;

    // A job: Ada reads the rendered slip, Bob is an observer.
    nav(&c, "jobs").await;
    c.wait().for_element(Locator::Css("#create-job")).await.unwrap();
    assert_all_labelled(&c, "jobs").await;
    let ids = c
        .execute(
            "const pick = (sel, text) => [...document.querySelectorAll(sel + ' option')].find(o => o.textContent.includes(text)).value; \
             return [pick('#create-job select[data-field=profile_id]', 'Ada'), pick('#create-job select[data-field=document_id]', '48×48')];",
            vec![],
        )
        .await
        .unwrap();
    input_labelled(&c, "#create-job", "Who must read it")
        .await
        .select_by_value(ids[0].as_str().unwrap())
        .await
        .unwrap();
    input_labelled(&c, "#create-job", "Document")
        .await
        .select_by_value(ids[1].as_str().unwrap())
        .await
        .unwrap();
    // The one trade-off knob: strict (no target states) keeps the console's job small.
    input_labelled(&c, "#create-job", "Security")
        .await
        .select_by_value("strict")
        .await
        .unwrap();
    c.find(Locator::XPath(
        "//form[@id='create-job']//label[contains(., 'Bob')]/input",
    ))
    .await
    .unwrap()
    .click()
    .await
    .unwrap();
    let options = input_labelled(&c, "#create-job", "Other encoder options (JSON, optional)").await;
    options.send_keys(&fast_options().to_string()).await.unwrap();
    click(&c, "#create-job button[type=submit]").await;
    wait_until(
        &c,
        "the job page",
        "return location.pathname.startsWith('/console/jobs/') && !!document.getElementById('job-state')",
        15,
    )
    .await;
    let job_id = c
        .current_url()
        .await
        .unwrap()
        .path()
        .rsplit('/')
        .next()
        .unwrap()
        .to_string();
    wait_until(
        &c,
        "the job to succeed",
        "return document.getElementById('job-state').textContent.includes('succeeded')",
        180,
    )
    .await;
    assert_eq!(
        c.find(Locator::Id("job-security")).await.unwrap().text().await.unwrap(),
        "strict",
        "the job page says which security level the job was asked for"
    );
    wait_until(
        &c,
        "every view to load",
        "const imgs = [...document.querySelectorAll('#views img')]; \
         return imgs.length >= 5 && imgs.every(i => i.dataset.state === 'loaded' && i.complete && i.naturalWidth > 0)",
        30,
    )
    .await;
    let shown = c
        .execute(
            "return [...document.querySelectorAll('#views figure')].map(f => f.dataset.view)",
            vec![],
        )
        .await
        .unwrap();
    for view in [
        "objective.png",
        "target.png",
        "population_worst.png",
        "observer_0.png",
        "camera_best.png",
    ] {
        assert!(
            shown.as_array().unwrap().contains(&json!(view)),
            "{view} missing from {shown}"
        );
    }
    assert!(
        c.find(Locator::Css("#population-plot rect")).await.is_ok(),
        "the population plot has bars"
    );
    let verdicts = c.find_all(Locator::Css("#verdicts tbody tr")).await.unwrap();
    assert!(verdicts.len() >= 4, "target, bystander, most legible person and camera");
    let verdict_table = text_of(&c, "#verdicts").await;
    assert!(verdict_table.contains("Bystander Bob"));
    // Bob may refocus: his row says at which focus he was judged (his own, or so many dioptres nearer or farther).
    let bob = verdict_table
        .lines()
        .find(|l| l.contains("Bystander Bob"))
        .unwrap()
        .to_string();
    assert!(
        bob.contains("own focus") || bob.contains(" D (nearer)") || bob.contains(" D (farther)"),
        "{bob}"
    );
    assert!(
        text_of(&c, "#population-summary").await.contains("at their own focus"),
        "the population summary tells readers at their own focus from those who refocused"
    );
    wait_until(
        &c,
        "the job's audit log",
        "return !!document.querySelector('#job-audit table')",
        10,
    )
    .await;
    assert!(text_of(&c, "#job-audit").await.contains("job.create"));
    shot(&c, "job").await;

    // The jobs list shows it finished; the audit page lists what was done.
    nav(&c, "jobs").await;
    wait_until(
        &c,
        "the jobs list",
        &format!("return !!document.querySelector('#jobs a[href=\"/console/jobs/{job_id}\"]')"),
        10,
    )
    .await;
    assert!(text_of(&c, "#jobs").await.contains("succeeded"));
    shot(&c, "jobs").await;
    nav(&c, "audit").await;
    wait_until(
        &c,
        "the audit page",
        "return !!document.querySelector('main table.audit')",
        10,
    )
    .await;
    assert!(text_of(&c, "main table.audit").await.contains("display.register"));
    shot(&c, "audit").await;

    let errors = browser_errors(&c).await;
    assert!(errors.is_empty(), "browser console errors: {errors:#?}");

    // Signing out forgets the token.
    click(&c, "#sign-out").await;
    c.wait().for_element(Locator::Css("#sign-in")).await.unwrap();
    let kept = c.execute("return sessionStorage.length", vec![]).await.unwrap();
    assert_eq!(kept, json!(0));
    c.goto(&app.url("/console/jobs")).await.unwrap();
    c.wait().for_element(Locator::Css("#sign-in")).await.unwrap();

    c.close().await.unwrap();
    drop(driver);
    app.stop().await;
}
