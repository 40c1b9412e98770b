//! The OpenAPI document, generated from the handlers' `#[utoipa::path]` annotations.
//!
//! Served at `/openapi.json` (with Swagger UI at `/docs`) and committed at `openapi/openapi.json`; the
//! test suite fails when the two differ. Regenerate with
//! `EYEKEY_WRITE_OPENAPI=1 cargo test --test api openapi`.

use utoipa::openapi::security::{Http, HttpAuthScheme, SecurityScheme};
use utoipa::{Modify, OpenApi};

use super::routes;

/// The service's API.
#[derive(OpenApi)]
#[openapi(
    info(
        title = "eyekey",
        description = "Shows a document on a light-field display so that only one enrolled person can read it. \
            Operators (operator token) enrol vision profiles, register displays, upload documents, run encoding \
            jobs and read their evaluation; each display client (its own token) fetches the frame bundles of its \
            own jobs. A missing or unknown token gets 401; a display token on an operator route, or the operator \
            token on a display route, gets 403; another display's job is a 404 to a display. Every error body \
            is `{\"error\": {\"code\", \"message\", \"field\"}}`."
    ),
    paths(
        routes::health::healthz,
        routes::health::readyz,
        routes::metrics::scrape,
        routes::profiles::enrol_profile,
        routes::profiles::list_profiles,
        routes::profiles::get_profile,
        routes::profiles::reenrol_profile,
        routes::profiles::delete_profile,
        routes::displays::register_display,
        routes::displays::list_displays,
        routes::displays::get_display,
        routes::displays::rotate_token,
        routes::displays::delete_display,
        routes::documents::upload_document,
        routes::documents::list_documents,
        routes::documents::get_document,
        routes::documents::delete_document,
        routes::jobs::create_job,
        routes::jobs::list_jobs,
        routes::jobs::get_job,
        routes::jobs::cancel_job,
        routes::jobs::delete_job,
        routes::jobs::job_events,
        routes::evaluation::get_evaluation,
        routes::evaluation::get_encoding,
        routes::evaluation::list_views,
        routes::evaluation::get_view,
        routes::frames::list_frame_jobs,
        routes::frames::get_frame_job,
        routes::frames::download_bundle,
        routes::frames::download_file,
        routes::frames::frame_events,
        routes::audit::list_audit,
        routes::tokens::create_token,
        routes::tokens::list_tokens,
        routes::tokens::revoke_token,
        routes::tokens::me,
        routes::documents::render_document,
        routes::documents::get_document_image,
    ),
    modifiers(&BearerSchemes, &CommonResponses, &TaggedVariants),
    tags(
        (name = "profiles", description = "Enrolled vision profiles (operator)"),
        (name = "displays", description = "Registered light-field displays (operator)"),
        (name = "documents", description = "Uploaded documents (operator)"),
        (name = "jobs", description = "Encoding jobs (operator)"),
        (name = "evaluation", description = "Reports and simulated views of succeeded jobs (operator)"),
        (name = "frames", description = "Frame bundles for a display client (display token)"),
        (name = "audit", description = "Append-only audit log (operator, admin scope)"),
        (name = "tokens", description = "Scoped operator tokens (operator, admin scope); the caller's own scopes (any scope)"),
        (name = "operations", description = "Health and readiness (no token); metrics (operator, admin scope)"),
    )
)]
pub struct ApiDoc;

/// Declares the two bearer-token schemes.
struct BearerSchemes;

impl Modify for BearerSchemes {
    fn modify(&self, openapi: &mut utoipa::openapi::OpenApi) {
        let components = openapi.components.get_or_insert_with(Default::default);
        let mut operator = Http::new(HttpAuthScheme::Bearer);
        operator.description = Some(
            "An operator token: the bootstrap token (EYEKEY_OPERATOR_TOKEN or <data-dir>/operator-token, scope admin) or one \
             made with POST /v1/tokens; each operation needs one of the scopes its description names"
                .into(),
        );
        components.add_security_scheme("operator", SecurityScheme::Http(operator));
        let mut display = Http::new(HttpAuthScheme::Bearer);
        display.description = Some("A display's access token, shown once at registration or rotation".into());
        components.add_security_scheme("display", SecurityScheme::Http(display));
    }
}

/// The error statuses any operation can answer besides its own: a malformed path, query or body (400), a
/// token of the wrong role or scope (403), a body over its limit (413), a body of the wrong type (415), a field
/// out of range (422), an internal error (500), not ready or a read-only data directory (503), and a full
/// data directory (507). Each operation's own list is kept; these are added where it does not name them, so a
/// client generated from the document knows every status it can meet.
struct CommonResponses;

impl Modify for CommonResponses {
    fn modify(&self, openapi: &mut utoipa::openapi::OpenApi) {
        use utoipa::openapi::{ContentBuilder, Ref, ResponseBuilder};
        let common: [(&str, &str, bool); 8] = [
            ("400", "Malformed path, query or body", true),
            ("403", "The token's role or scopes do not allow this", true),
            ("413", "The body exceeds its limit", false),
            ("415", "The body's content type is not accepted", false),
            (
                "422",
                "A field is out of range or refers to nothing; `field` names it",
                true,
            ),
            ("500", "Internal error (logged; the body says no more)", true),
            (
                "503",
                "Not ready, shutting down, or the data directory is read-only",
                true,
            ),
            ("507", "The data directory is full; nothing was stored", false),
        ];
        for item in openapi.paths.paths.values_mut() {
            let ops = [
                item.get.as_mut(),
                item.put.as_mut(),
                item.post.as_mut(),
                item.delete.as_mut(),
                item.patch.as_mut(),
            ];
            for op in ops.into_iter().flatten() {
                let has_body = op.request_body.is_some();
                let writes = has_body || op.operation_id.as_deref().is_some_and(|id| id.starts_with("delete"));
                for (code, description, always) in common {
                    let applies = always || (code == "507" && writes) || (code != "507" && has_body);
                    if applies && !op.responses.responses.contains_key(code) {
                        let response = ResponseBuilder::new()
                            .description(description)
                            .content(
                                "application/json",
                                ContentBuilder::new()
                                    .schema(Some(Ref::from_schema_name("ErrorBody")))
                                    .build(),
                            )
                            .build();
                        op.responses.responses.insert(code.to_string(), response.into());
                    }
                }
            }
        }
    }
}

/// An internally tagged enum's newtype variant is `allOf: [$ref X, {tag}]`; when X forbids unknown fields
/// (`additionalProperties: false`), no object can satisfy both, so the variant would match nothing. The tag is
/// declared on X as well, which is what serde accepts (`{"kind": "parameters", ...}`).
struct TaggedVariants;

impl Modify for TaggedVariants {
    fn modify(&self, openapi: &mut utoipa::openapi::OpenApi) {
        use utoipa::openapi::schema::{AdditionalProperties, Schema};
        use utoipa::openapi::RefOr;
        let Some(components) = openapi.components.as_mut() else {
            return;
        };
        let mut tags = Vec::new();
        for schema in components.schemas.values() {
            let RefOr::T(Schema::OneOf(one_of)) = schema else {
                continue;
            };
            for item in &one_of.items {
                let RefOr::T(Schema::AllOf(all_of)) = item else {
                    continue;
                };
                let target = all_of.items.iter().find_map(|part| match part {
                    RefOr::Ref(r) => r.ref_location.strip_prefix("#/components/schemas/").map(str::to_owned),
                    _ => None,
                });
                let tag = all_of.items.iter().find_map(|part| match part {
                    RefOr::T(Schema::Object(o)) => Some(o.properties.clone()),
                    _ => None,
                });
                if let (Some(target), Some(tag)) = (target, tag) {
                    tags.push((target, tag));
                }
            }
        }
        for (target, tag) in tags {
            if let Some(RefOr::T(Schema::Object(object))) = components.schemas.get_mut(&target) {
                if matches!(
                    object.additional_properties.as_deref(),
                    Some(AdditionalProperties::FreeForm(false))
                ) {
                    object.properties.extend(tag);
                }
            }
        }
    }
}

/// The document as committed: pretty JSON with a trailing newline.
pub fn document_json() -> String {
    let mut text = ApiDoc::openapi().to_pretty_json().unwrap_or_default();
    text.push('\n');
    text
}
