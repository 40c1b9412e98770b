//! Secrets: the master key that seals vision profiles, and bearer tokens.
//!
//! Profiles are sealed with ChaCha20-Poly1305 under the master key, a fresh random 96-bit nonce per
//! version, and the profile id and version as associated data, so a ciphertext moved to another row
//! does not open. Tokens are random 32 bytes; only their SHA-256 is kept, and comparisons of hashes are
//! constant-time.

use base64::Engine as _;
use chacha20poly1305::aead::{Aead, KeyInit, Payload};
use chacha20poly1305::{ChaCha20Poly1305, Key, Nonce};
use rand::RngCore as _;
use sha2::{Digest, Sha256};
use subtle::ConstantTimeEq as _;

/// Length of a nonce, bytes.
pub const NONCE_LEN: usize = 12;

/// Errors of key handling and sealing.
#[derive(Debug, thiserror::Error)]
pub enum CryptoError {
    /// The key text is not 64 hex digits.
    #[error("the master key must be 64 hex digits (32 bytes)")]
    BadKey,
    /// Authentication failed: wrong key, wrong associated data, or a damaged ciphertext.
    #[error("ciphertext did not authenticate (wrong master key or damaged data)")]
    Open,
    /// Sealing failed (not expected with a valid key).
    #[error("sealing failed")]
    Seal,
}

/// The 256-bit key under which profiles are sealed. Its `Debug` does not print it.
#[derive(Clone)]
pub struct MasterKey(Key);

impl std::fmt::Debug for MasterKey {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("MasterKey(..)")
    }
}

/// A sealed value.
#[derive(Clone, Debug)]
pub struct Sealed {
    /// The random nonce.
    pub nonce: Vec<u8>,
    /// Ciphertext with its 16-byte tag.
    pub ciphertext: Vec<u8>,
}

impl MasterKey {
    /// Parses 64 hex digits (surrounding whitespace ignored).
    pub fn from_hex(text: &str) -> Result<Self, CryptoError> {
        let bytes = hex::decode(text.trim()).map_err(|_| CryptoError::BadKey)?;
        if bytes.len() != 32 {
            return Err(CryptoError::BadKey);
        }
        Ok(Self(*Key::from_slice(&bytes)))
    }

    /// A fresh random key, as 64 hex digits.
    pub fn generate_hex() -> String {
        let mut k = [0u8; 32];
        rand::rngs::OsRng.fill_bytes(&mut k);
        hex::encode(k)
    }

    /// Seals `plaintext`, binding it to `aad`.
    pub fn seal(&self, plaintext: &[u8], aad: &[u8]) -> Result<Sealed, CryptoError> {
        let mut nonce = [0u8; NONCE_LEN];
        rand::rngs::OsRng.fill_bytes(&mut nonce);
        let ciphertext = ChaCha20Poly1305::new(&self.0)
            .encrypt(Nonce::from_slice(&nonce), Payload { msg: plaintext, aad })
            .map_err(|_| CryptoError::Seal)?;
        Ok(Sealed {
            nonce: nonce.to_vec(),
            ciphertext,
        })
    }

    /// Opens a value sealed with the same key and `aad`.
    pub fn open(&self, nonce: &[u8], ciphertext: &[u8], aad: &[u8]) -> Result<Vec<u8>, CryptoError> {
        if nonce.len() != NONCE_LEN {
            return Err(CryptoError::Open);
        }
        ChaCha20Poly1305::new(&self.0)
            .decrypt(Nonce::from_slice(nonce), Payload { msg: ciphertext, aad })
            .map_err(|_| CryptoError::Open)
    }
}

/// Associated data binding a sealed profile to its row.
pub fn profile_aad(profile_id: &str, version: i64) -> Vec<u8> {
    format!("eyekey-profile:{profile_id}:{version}").into_bytes()
}

/// A new random bearer token: `prefix` followed by 32 random bytes in unpadded base64url.
pub fn generate_token(prefix: &str) -> String {
    let mut bytes = [0u8; 32];
    rand::rngs::OsRng.fill_bytes(&mut bytes);
    format!(
        "{prefix}{}",
        base64::engine::general_purpose::URL_SAFE_NO_PAD.encode(bytes)
    )
}

/// SHA-256 of a token; the only form in which tokens are stored.
pub fn token_hash(token: &str) -> [u8; 32] {
    Sha256::digest(token.as_bytes()).into()
}

/// Constant-time equality of two hashes.
pub fn hashes_equal(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && bool::from(a.ct_eq(b))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sealed_profile_opens_only_with_its_own_id_and_version() {
        let key = MasterKey::from_hex(&MasterKey::generate_hex()).unwrap();
        let sealed = key.seal(b"{\"zernike_um\":[0.1]}", &profile_aad("p1", 1)).unwrap();
        assert_eq!(
            key.open(&sealed.nonce, &sealed.ciphertext, &profile_aad("p1", 1))
                .unwrap(),
            b"{\"zernike_um\":[0.1]}"
        );
        assert!(key
            .open(&sealed.nonce, &sealed.ciphertext, &profile_aad("p1", 2))
            .is_err());
        assert!(key
            .open(&sealed.nonce, &sealed.ciphertext, &profile_aad("p2", 1))
            .is_err());
        let other = MasterKey::from_hex(&MasterKey::generate_hex()).unwrap();
        assert!(other
            .open(&sealed.nonce, &sealed.ciphertext, &profile_aad("p1", 1))
            .is_err());
    }

    #[test]
    fn keys_must_be_64_hex_digits() {
        assert!(MasterKey::from_hex("abcd").is_err());
        assert!(MasterKey::from_hex(&"zz".repeat(32)).is_err());
        assert!(MasterKey::from_hex(&format!(" {}\n", "ab".repeat(32))).is_ok());
    }

    #[test]
    fn tokens_are_distinct_and_compare_by_hash() {
        let (a, b) = (generate_token("ekd_"), generate_token("ekd_"));
        assert_ne!(a, b);
        assert!(a.starts_with("ekd_") && a.len() == 4 + 43);
        assert!(hashes_equal(&token_hash(&a), &token_hash(&a)));
        assert!(!hashes_equal(&token_hash(&a), &token_hash(&b)));
    }
}
