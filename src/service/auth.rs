//! Bearer-token roles: operators (the bootstrap token from the configuration, with the `admin` scope, and
//! scoped tokens made with `POST /v1/tokens`, stored hashed) and display clients (one token per registered
//! display, stored hashed).
//!
//! Deny by default: every operator handler names the scope it needs in its extractor's type
//! (`Operator<scope::Submit>`, say); `admin` holds every scope.

use std::marker::PhantomData;

use axum::extract::FromRequestParts;
use axum::http::header;
use axum::http::request::Parts;
use serde::{Deserialize, Serialize};

use super::crypto::{hashes_equal, token_hash};
use super::error::ApiError;
use super::state::AppState;
use super::store;

/// What an operator token may do.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "kebab-case")]
pub enum Scope {
    /// Enrol, read, re-enrol and delete vision profiles.
    Enrol,
    /// Upload and delete documents; create, cancel and delete jobs; read jobs and displays.
    Submit,
    /// Read jobs and their evaluations and simulated views.
    ReadEvaluation,
    /// Everything, including displays, tokens, the audit log and metrics.
    Admin,
}

impl Scope {
    /// The wire name.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Enrol => "enrol",
            Self::Submit => "submit",
            Self::ReadEvaluation => "read-evaluation",
            Self::Admin => "admin",
        }
    }
}

/// The scopes an extractor accepts (any one of them, or `admin`).
pub trait Required {
    /// Accepted scopes besides `admin`.
    const ANY_OF: &'static [Scope];
}

/// Marker types naming what a handler needs.
pub mod scope {
    use super::{Required, Scope};

    /// `enrol`.
    #[derive(Debug)]
    pub struct Enrol;
    /// `submit`.
    #[derive(Debug)]
    pub struct Submit;
    /// `read-evaluation`.
    #[derive(Debug)]
    pub struct ReadEvaluation;
    /// Reading jobs: `submit` or `read-evaluation`.
    #[derive(Debug)]
    pub struct ReadJobs;
    /// `admin` only.
    #[derive(Debug)]
    pub struct Admin;
    /// Any operator token, whatever its scopes.
    #[derive(Debug)]
    pub struct AnyScope;

    impl Required for Enrol {
        const ANY_OF: &'static [Scope] = &[Scope::Enrol];
    }
    impl Required for Submit {
        const ANY_OF: &'static [Scope] = &[Scope::Submit];
    }
    impl Required for ReadEvaluation {
        const ANY_OF: &'static [Scope] = &[Scope::ReadEvaluation];
    }
    impl Required for ReadJobs {
        const ANY_OF: &'static [Scope] = &[Scope::Submit, Scope::ReadEvaluation];
    }
    impl Required for Admin {
        const ANY_OF: &'static [Scope] = &[];
    }
    impl Required for AnyScope {
        const ANY_OF: &'static [Scope] = &[Scope::Enrol, Scope::Submit, Scope::ReadEvaluation];
    }
}

/// The caller presented an operator token with a scope `R` accepts.
#[derive(Debug)]
pub struct Operator<R = scope::Admin> {
    /// The token's name (`operator` for the bootstrap token).
    pub name: String,
    /// Its scopes.
    pub scopes: Vec<Scope>,
    _required: PhantomData<R>,
}

impl<R> Operator<R> {
    /// The audit actor name: `operator` for the bootstrap token, `token:<name>` for a scoped one.
    pub fn actor(&self) -> String {
        if self.name == OPERATOR {
            OPERATOR.to_string()
        } else {
            format!("token:{}", self.name)
        }
    }
}

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

/// The audit actor name of the bootstrap operator token.
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

/// The operator a token hash belongs to: (name, scopes).
async fn operator_for(state: &AppState, hash: &[u8; 32]) -> Result<Option<(String, Vec<Scope>)>, ApiError> {
    if hashes_equal(hash, &state.operator_token_hash) {
        return Ok(Some((OPERATOR.to_string(), vec![Scope::Admin])));
    }
    let Some(row) = store::tokens::by_hash(&state.db, hash).await? else {
        return Ok(None);
    };
    if !hashes_equal(&row.token_hash, hash) {
        return Ok(None);
    }
    let scopes: Vec<Scope> = serde_json::from_str(&row.scopes)
        .map_err(|e| ApiError::Internal(anyhow::anyhow!("stored scopes of token {}: {e}", row.id)))?;
    Ok(Some((row.name, scopes)))
}

impl<R: Required + Send + Sync> FromRequestParts<AppState> for Operator<R> {
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, state: &AppState) -> Result<Self, ApiError> {
        let token = bearer(parts).ok_or(ApiError::Unauthorized)?;
        let hash = token_hash(token);
        if let Some((name, scopes)) = operator_for(state, &hash).await? {
            if scopes.contains(&Scope::Admin) || R::ANY_OF.iter().any(|s| scopes.contains(s)) {
                return Ok(Operator {
                    name,
                    scopes,
                    _required: PhantomData,
                });
            }
            let needed: Vec<&str> = R::ANY_OF.iter().chain([&Scope::Admin]).map(|s| s.as_str()).collect();
            return Err(ApiError::Forbidden(format!(
                "the token {name:?} lacks the scope for this: it needs one of {}",
                needed.join(", ")
            )));
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
        if operator_for(state, &hash).await?.is_some() {
            return Err(ApiError::Forbidden(
                "/v1/frames is for display clients; operators use /v1/jobs".into(),
            ));
        }
        Err(ApiError::Unauthorized)
    }
}
