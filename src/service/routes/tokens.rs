//! `/v1/tokens`: scoped operator tokens (admin only). A token's secret is shown once, when it is made, and
//! stored as its SHA-256; its name is recorded in the audit log for everything done with it.

use axum::extract::State;
use axum::http::StatusCode;
use axum::routing::{delete, get};
use axum::{Json, Router};
use chrono::{DateTime, Utc};
use serde::{Deserialize, Serialize};
use uuid::Uuid;

use super::{check_name, id_text, next_cursor, PageQuery};
use crate::service::auth::{scope, Operator, Scope, OPERATOR};
use crate::service::crypto::{generate_token, token_hash};
use crate::service::error::{ApiError, ApiJson, ApiPath, ApiQuery, ErrorBody};
use crate::service::state::AppState;
use crate::service::store::{self, to_time, tokens::TokenRow};

/// Routes of this resource.
pub fn router() -> Router<AppState> {
    Router::new()
        .route("/v1/tokens", get(list_tokens).post(create_token))
        .route("/v1/tokens/{id}", delete(revoke_token))
        .route("/v1/me", get(me))
}

/// Who a token is: its name and scopes.
#[derive(Debug, Serialize, Deserialize, utoipa::ToSchema)]
pub struct Me {
    /// The token's name (`operator` for the bootstrap token).
    pub name: String,
    /// Its scopes; `admin` holds every other.
    pub scopes: Vec<Scope>,
}

/// The calling operator token's name and scopes (any scope), so a client can offer only what the token may do.
#[utoipa::path(
    get, path = "/v1/me", tag = "tokens",
    responses(
        (status = 200, description = "The token's name and scopes", body = Me),
        (status = 401, description = "No or unknown token", body = ErrorBody),
    ),
    security(("operator" = ["enrol", "submit", "read-evaluation", "admin"]))
)]
pub async fn me(op: Operator<scope::AnyScope>) -> Json<Me> {
    Json(Me {
        name: op.name,
        scopes: op.scopes,
    })
}

/// Operator tokens start with this, so a leaked one is recognisable.
const TOKEN_PREFIX: &str = "eko_";

/// Body of a token creation.
#[derive(Debug, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct CreateToken {
    /// Who or what holds it, recorded in the audit log (1–100 characters, unique among live tokens, no
    /// control or bidirectional-override characters).
    #[schema(
        min_length = 1,
        max_length = 100,
        pattern = r"^[^\u0000-\u001F\u007F-\u009F\u00AD\u0600-\u0605\u061C\u06DD\u070F\u180E\u200B-\u200F\u202A-\u202E\u2060-\u2064\u2066-\u206F\uFEFF\uFFF9-\uFFFB]*[^\s\u0000-\u001F\u007F-\u009F\u00AD\u0600-\u0605\u061C\u06DD\u070F\u180E\u200B-\u200F\u202A-\u202E\u2060-\u2064\u2066-\u206F\uFEFF\uFFF9-\uFFFB][^\u0000-\u001F\u007F-\u009F\u00AD\u0600-\u0605\u061C\u06DD\u070F\u180E\u200B-\u200F\u202A-\u202E\u2060-\u2064\u2066-\u206F\uFEFF\uFFF9-\uFFFB]*$"
    )]
    pub name: String,
    /// What it may do: one or more of `enrol`, `submit`, `read-evaluation`, `admin`.
    #[schema(min_items = 1, max_items = 4)]
    pub scopes: Vec<Scope>,
}

/// A token as listed (never its secret).
#[derive(Debug, Serialize, Deserialize, utoipa::ToSchema)]
pub struct TokenView {
    /// Id.
    pub id: Uuid,
    /// Name.
    pub name: String,
    /// Scopes.
    pub scopes: Vec<Scope>,
    /// Creation time.
    pub created_at: DateTime<Utc>,
}

/// A new token with its secret, shown only in this response.
#[derive(Debug, Serialize, Deserialize, utoipa::ToSchema)]
pub struct TokenWithSecret {
    /// The token.
    pub token: TokenView,
    /// The bearer secret; store it now, it cannot be shown again.
    pub secret: String,
}

/// A page of tokens.
#[derive(Debug, Serialize, Deserialize, utoipa::ToSchema)]
pub struct TokenList {
    /// Live tokens, newest first.
    pub items: Vec<TokenView>,
    /// Pass as `cursor` for the next page; absent on the last page.
    pub next_cursor: Option<String>,
}

fn view(r: &TokenRow) -> Result<TokenView, ApiError> {
    Ok(TokenView {
        id: r.id.parse().unwrap_or_default(),
        name: r.name.clone(),
        scopes: serde_json::from_str(&r.scopes).map_err(|e| ApiError::Internal(e.into()))?,
        created_at: to_time(r.created_at),
    })
}

/// Make a scoped operator token.
#[utoipa::path(
    post, path = "/v1/tokens", tag = "tokens",
    request_body = CreateToken,
    responses(
        (status = 201, description = "Made; the secret is shown once", body = TokenWithSecret),
        (status = 401, description = "No or unknown token", body = ErrorBody),
        (status = 403, description = "Not an admin token", body = ErrorBody),
        (status = 409, description = "A live token has this name", body = ErrorBody),
        (status = 422, description = "Bad name or scopes", body = ErrorBody),
    ),
    security(("operator" = ["admin"]))
)]
pub async fn create_token(
    State(state): State<AppState>,
    op: Operator<scope::Admin>,
    ApiJson(body): ApiJson<CreateToken>,
) -> Result<(StatusCode, Json<TokenWithSecret>), ApiError> {
    let name = check_name("name", &body.name, 100)?;
    if name == OPERATOR {
        return Err(ApiError::invalid("name", "`operator` is the bootstrap token's name"));
    }
    if body.scopes.len() > 4 {
        return Err(ApiError::invalid("scopes", "at most 4 scopes"));
    }
    let mut scopes = body.scopes.clone();
    scopes.sort_by_key(|s| s.as_str());
    scopes.dedup();
    if scopes.is_empty() {
        return Err(ApiError::invalid("scopes", "give at least one scope"));
    }
    let id = id_text(&Uuid::new_v4());
    let secret = generate_token(TOKEN_PREFIX);
    let scopes_json = serde_json::to_string(&scopes).map_err(|e| ApiError::Internal(e.into()))?;
    let row = store::tokens::insert(&state.writer, &id, name, &scopes_json, &token_hash(&secret))
        .await?
        .ok_or_else(|| ApiError::Conflict {
            code: "token_name_taken",
            message: format!("a live token is already named {name:?}; revoke it or choose another name"),
        })?;
    store::audit::record(&state.writer, &op.actor(), "token.create", &format!("tokens/{id}")).await?;
    Ok((
        StatusCode::CREATED,
        Json(TokenWithSecret {
            token: view(&row)?,
            secret,
        }),
    ))
}

/// List live tokens (never their secrets).
#[utoipa::path(
    get, path = "/v1/tokens", tag = "tokens",
    params(PageQuery),
    responses(
        (status = 200, description = "A page of tokens", body = TokenList),
        (status = 401, description = "No or unknown token", body = ErrorBody),
        (status = 403, description = "Not an admin token", body = ErrorBody),
    ),
    security(("operator" = ["admin"]))
)]
pub async fn list_tokens(
    State(state): State<AppState>,
    _op: Operator<scope::Admin>,
    ApiQuery(page): ApiQuery<PageQuery>,
) -> Result<Json<TokenList>, ApiError> {
    let (limit, cursor) = page.parse()?;
    let rows = store::tokens::list(&state.db, limit, cursor.as_ref()).await?;
    Ok(Json(TokenList {
        next_cursor: next_cursor(&rows, limit, |r| (r.created_at, r.id.clone())),
        items: rows.iter().map(view).collect::<Result<_, _>>()?,
    }))
}

/// Revoke a token: it stops authenticating at once.
#[utoipa::path(
    delete, path = "/v1/tokens/{id}", tag = "tokens",
    params(("id" = Uuid, Path, description = "Token id")),
    responses(
        (status = 204, description = "Revoked"),
        (status = 401, description = "No or unknown token", body = ErrorBody),
        (status = 403, description = "Not an admin token", body = ErrorBody),
        (status = 404, description = "No such live token", body = ErrorBody),
    ),
    security(("operator" = ["admin"]))
)]
pub async fn revoke_token(
    State(state): State<AppState>,
    op: Operator<scope::Admin>,
    ApiPath(id): ApiPath<Uuid>,
) -> Result<StatusCode, ApiError> {
    let id = id_text(&id);
    if !store::tokens::revoke(&state.writer, &id).await? {
        return Err(ApiError::NotFound("token"));
    }
    store::audit::record(&state.writer, &op.actor(), "token.revoke", &format!("tokens/{id}")).await?;
    Ok(StatusCode::NO_CONTENT)
}
