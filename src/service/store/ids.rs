//! Typed resource ids.
//!
//! Ids are UUIDs, stored as TEXT in the hyphenated lower-case form (`Uuid::to_string`), as the schema
//! says, on SQLite and PostgreSQL alike. The store speaks to both through sqlx's `Any` driver, which knows
//! no UUID type, so these types implement sqlx's `Type`, `Encode` and `Decode` for `Any` by hand, as that
//! text. In JSON they are the same hyphenated string (`#[serde(transparent)]`).

use std::fmt;
use std::str::FromStr;

use sqlx::any::{AnyTypeInfo, AnyValueRef};
use sqlx::encode::IsNull;
use sqlx::error::BoxDynError;
use sqlx::{Any, Database};
use uuid::Uuid;

/// Defines a `Uuid` newtype stored as hyphenated TEXT.
macro_rules! text_uuid_id {
    ($(#[$meta:meta])* $name:ident) => {
        $(#[$meta])*
        #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize, serde::Deserialize)]
        #[serde(transparent)]
        pub struct $name(pub Uuid);

        impl $name {
            /// A fresh random (v4) id.
            pub fn new_v4() -> Self {
                Self(Uuid::new_v4())
            }

            /// The UUID.
            pub fn as_uuid(&self) -> Uuid {
                self.0
            }
        }

        impl From<Uuid> for $name {
            fn from(id: Uuid) -> Self {
                Self(id)
            }
        }

        impl From<$name> for Uuid {
            fn from(id: $name) -> Self {
                id.0
            }
        }

        /// The hyphenated lower-case form, as stored.
        impl fmt::Display for $name {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                fmt::Display::fmt(&self.0.hyphenated(), f)
            }
        }

        impl FromStr for $name {
            type Err = uuid::Error;
            fn from_str(s: &str) -> Result<Self, Self::Err> {
                Uuid::parse_str(s).map(Self)
            }
        }

        impl sqlx::Type<Any> for $name {
            fn type_info() -> AnyTypeInfo {
                <String as sqlx::Type<Any>>::type_info()
            }

            fn compatible(ty: &AnyTypeInfo) -> bool {
                <String as sqlx::Type<Any>>::compatible(ty)
            }
        }

        impl<'q> sqlx::Encode<'q, Any> for $name {
            fn encode_by_ref(&self, buf: &mut <Any as Database>::ArgumentBuffer<'q>) -> Result<IsNull, BoxDynError> {
                <String as sqlx::Encode<'q, Any>>::encode(self.to_string(), buf)
            }
        }

        impl<'r> sqlx::Decode<'r, Any> for $name {
            fn decode(value: AnyValueRef<'r>) -> Result<Self, BoxDynError> {
                let text = <String as sqlx::Decode<'r, Any>>::decode(value)?;
                Ok(Self(Uuid::parse_str(&text)?))
            }
        }
    };
}

text_uuid_id!(
    /// A job id (`jobs.id`).
    JobId
);

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn a_job_id_is_stored_and_read_back_as_hyphenated_text() {
        sqlx::any::install_default_drivers();
        let pool = sqlx::AnyPool::connect("sqlite::memory:").await.unwrap();
        let id = JobId::new_v4();
        let (text, kind): (String, String) = sqlx::query_as("SELECT $1, typeof($1)")
            .bind(id)
            .fetch_one(&pool)
            .await
            .unwrap();
        assert_eq!((text.as_str(), kind.as_str()), (id.0.to_string().as_str(), "text"));
        let (back,): (JobId,) = sqlx::query_as("SELECT $1").bind(&text).fetch_one(&pool).await.unwrap();
        assert_eq!(back, id);
        assert_eq!(serde_json::to_string(&id).unwrap(), format!("\"{text}\""));
        assert_eq!(id.to_string(), text);
    }
}
