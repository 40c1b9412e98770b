//! Secrets: the master key, the data keys it wraps, keyed digests, and bearer tokens.
//!
//! Profiles are sealed with ChaCha20-Poly1305 (RFC 8439) under the master key, a fresh random 96-bit nonce
//! per version, and the profile id and version as associated data, so a ciphertext moved to another row
//! does not open. Documents and job outputs are sealed under a random data key of their own
//! ([`DataKey`]), which is stored only wrapped (sealed) by the master key: deleting the wrapped key destroys
//! every copy of the object, wherever its ciphertext still lies. Where content must be recognisable
//! (an upload's digest, a request's identity), it is a keyed HMAC-SHA256 (RFC 2104) under a key derived
//! from the master key, never a plain hash: a plain hash of a PIN slip is the PIN to anyone who can render
//! ten thousand candidates. Tokens are random 32 bytes; only their SHA-256 is kept, and comparisons of
//! hashes are constant-time.

use base64::Engine as _;
use chacha20poly1305::aead::{Aead, KeyInit, Payload};
use chacha20poly1305::{ChaCha20Poly1305, Key, Nonce};
use hmac::Mac as _;
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

impl MasterKey {
    /// A 256-bit subkey for `purpose`: HMAC-SHA256(master key, "eyekey-subkey:" ‖ purpose), so keys derived
    /// for different purposes are independent and none reveals the master key.
    fn subkey(&self, purpose: &str) -> [u8; 32] {
        let mut mac = <HmacSha256 as hmac::Mac>::new_from_slice(self.0.as_slice()).expect("HMAC takes any key length");
        mac.update(b"eyekey-subkey:");
        mac.update(purpose.as_bytes());
        mac.finalize().into_bytes().into()
    }

    /// HMAC-SHA256 of `bytes` under the subkey for `purpose`, hex: recognises equal content without
    /// revealing it to anyone who lacks the master key.
    pub fn digest(&self, purpose: &str, bytes: &[u8]) -> String {
        let mut mac =
            <HmacSha256 as hmac::Mac>::new_from_slice(&self.subkey(purpose)).expect("HMAC takes any key length");
        mac.update(bytes);
        hex::encode(mac.finalize().into_bytes())
    }
}

type HmacSha256 = hmac::Hmac<Sha256>;

/// The random key one object (a document, or a job's outputs) is sealed under. Stored only wrapped by the
/// master key ([`DataKey::wrap`]); its `Debug` does not print it.
#[derive(Clone)]
pub struct DataKey(Key);

impl std::fmt::Debug for DataKey {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("DataKey(..)")
    }
}

impl DataKey {
    /// A fresh random key.
    pub fn generate() -> Self {
        let mut k = [0u8; 32];
        rand::rngs::OsRng.fill_bytes(&mut k);
        Self(*Key::from_slice(&k))
    }

    /// The key sealed under the master key, bound to `aad` (which names the object): nonce ‖ ciphertext.
    pub fn wrap(&self, master: &MasterKey, aad: &[u8]) -> Result<Vec<u8>, CryptoError> {
        let sealed = master.seal(self.0.as_slice(), aad)?;
        Ok(joined(sealed))
    }

    /// Opens a key [`DataKey::wrap`] produced with the same master key and `aad`.
    pub fn unwrap(master: &MasterKey, wrapped: &[u8], aad: &[u8]) -> Result<Self, CryptoError> {
        let (nonce, ct) = wrapped.split_at(NONCE_LEN.min(wrapped.len()));
        let plain = master.open(nonce, ct, aad)?;
        if plain.len() != 32 {
            return Err(CryptoError::Open);
        }
        Ok(Self(*Key::from_slice(&plain)))
    }

    /// Seals `plaintext` bound to `aad`: nonce ‖ ciphertext ‖ tag.
    pub fn seal(&self, plaintext: &[u8], aad: &[u8]) -> Result<Vec<u8>, CryptoError> {
        let mut nonce = [0u8; NONCE_LEN];
        rand::rngs::OsRng.fill_bytes(&mut nonce);
        let ciphertext = ChaCha20Poly1305::new(&self.0)
            .encrypt(Nonce::from_slice(&nonce), Payload { msg: plaintext, aad })
            .map_err(|_| CryptoError::Seal)?;
        Ok(joined(Sealed {
            nonce: nonce.to_vec(),
            ciphertext,
        }))
    }

    /// Opens what [`DataKey::seal`] produced with the same key and `aad`.
    pub fn open(&self, sealed: &[u8], aad: &[u8]) -> Result<Vec<u8>, CryptoError> {
        if sealed.len() < NONCE_LEN {
            return Err(CryptoError::Open);
        }
        let (nonce, ct) = sealed.split_at(NONCE_LEN);
        ChaCha20Poly1305::new(&self.0)
            .decrypt(Nonce::from_slice(nonce), Payload { msg: ct, aad })
            .map_err(|_| CryptoError::Open)
    }
}

fn joined(sealed: Sealed) -> Vec<u8> {
    let mut out = sealed.nonce;
    out.extend_from_slice(&sealed.ciphertext);
    out
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
    fn a_data_key_opens_only_what_it_sealed_under_the_same_name_and_unwraps_only_under_its_master_key() {
        let master = MasterKey::from_hex(&MasterKey::generate_hex()).unwrap();
        let key = DataKey::generate();
        let sealed = key.seal(b"PIN 4821", b"eyekey-document:d1").unwrap();
        assert_eq!(sealed.len(), NONCE_LEN + 8 + 16, "nonce, ciphertext and tag");
        assert!(!sealed.windows(8).any(|w| w == b"PIN 4821"));
        assert_eq!(key.open(&sealed, b"eyekey-document:d1").unwrap(), b"PIN 4821");
        assert!(key.open(&sealed, b"eyekey-document:d2").is_err());
        assert!(DataKey::generate().open(&sealed, b"eyekey-document:d1").is_err());
        let mut flipped = sealed.clone();
        flipped[NONCE_LEN] ^= 1;
        assert!(key.open(&flipped, b"eyekey-document:d1").is_err());

        let wrapped = key.wrap(&master, b"k1").unwrap();
        let back = DataKey::unwrap(&master, &wrapped, b"k1").unwrap();
        assert_eq!(back.open(&sealed, b"eyekey-document:d1").unwrap(), b"PIN 4821");
        assert!(DataKey::unwrap(&master, &wrapped, b"k2").is_err());
        let other = MasterKey::from_hex(&MasterKey::generate_hex()).unwrap();
        assert!(DataKey::unwrap(&other, &wrapped, b"k1").is_err());
    }

    #[test]
    fn digests_are_hmac_sha256_under_a_derived_key() {
        // RFC 4231 test case 2 checks the HMAC itself (key "Jefe").
        let mut mac = <HmacSha256 as hmac::Mac>::new_from_slice(b"Jefe").unwrap();
        hmac::Mac::update(&mut mac, b"what do ya want for nothing?");
        assert_eq!(
            hex::encode(hmac::Mac::finalize(mac).into_bytes()),
            "5bdcc146bf60754e6a042426089575c75a003f089d2739839dec58b964ec3843"
        );
        let key = MasterKey::from_hex(&"ab".repeat(32)).unwrap();
        let d = key.digest("document", b"PIN 4821");
        assert_eq!(d.len(), 64);
        assert_eq!(d, key.digest("document", b"PIN 4821"), "deterministic");
        assert_ne!(d, key.digest("request", b"PIN 4821"), "purposes are separate");
        assert_ne!(d, hex::encode(Sha256::digest(b"PIN 4821")), "not a plain hash");
        let other = MasterKey::from_hex(&"cd".repeat(32)).unwrap();
        assert_ne!(d, other.digest("document", b"PIN 4821"), "keyed");
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
