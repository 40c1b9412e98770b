//! Bearer-token roles: the operator (one token from the configuration) and display clients (one token
//! per registered display, stored hashed).

use axum::extract::FromRequestParts;
use axum::http::header;
use axum::http::request::Parts;

use super::crypto::{hashes_equal, token_hash};
use super::error::ApiError;
use super::state::AppState;
use super::store;

/// The caller presented the operator token.
#[derive(Clone, Copy, Debug)]
pub struct Operator;

/// The caller presented the token of this display.
#[derive(Clone, Debug)]
pub struct DisplayClient {
    /// The display's id.
    pub display_id: String,
}

impl DisplayClient {
    /// The audit actor name.
    pub fn actor(&self) -> String {
        format!("display:{}", self.display_id)
    }
}

/// The audit actor name of the operator.
pub const OPERATOR: &str = "operator";

fn bearer(parts: &Parts) -> Option<&str> {
    let value = parts.headers.get(header::AUTHORIZATION)?.to_str().ok()?;
    let (scheme, token) = value.split_once(' ')?;
    scheme
        .eq_ignore_ascii_case("bearer")
        .then(|| token.trim())
        .filter(|t| !t.is_empty())
}

async fn display_for(state: &AppState, hash: &[u8; 32]) -> Result<Option<store::displays::DisplayRow>, ApiError> {
    let row = store::displays::by_token_hash(&state.db, hash).await?;
    // The lookup is by an indexed hash; compare again in constant time so the decision itself never
    // depends on how many bytes matched.
    Ok(row.filter(|d| hashes_equal(&d.token_hash, hash)))
}

impl FromRequestParts<AppState> for Operator {
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, state: &AppState) -> Result<Self, ApiError> {
        let token = bearer(parts).ok_or(ApiError::Unauthorized)?;
        let hash = token_hash(token);
        if hashes_equal(&hash, &state.operator_token_hash) {
            return Ok(Operator);
        }
        if display_for(state, &hash).await?.is_some() {
            return Err(ApiError::Forbidden(
                "a display token may only read its own frames under /v1/frames".into(),
            ));
        }
        Err(ApiError::Unauthorized)
    }
}

impl FromRequestParts<AppState> for DisplayClient {
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, state: &AppState) -> Result<Self, ApiError> {
        let token = bearer(parts).ok_or(ApiError::Unauthorized)?;
        let hash = token_hash(token);
        if let Some(d) = display_for(state, &hash).await? {
            return Ok(DisplayClient { display_id: d.id });
        }
        if hashes_equal(&hash, &state.operator_token_hash) {
            return Err(ApiError::Forbidden(
                "/v1/frames is for display clients; operators use /v1/jobs".into(),
            ));
        }
        Err(ApiError::Unauthorized)
    }
}
