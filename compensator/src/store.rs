//! The device's persistent store: the model blob, its λ_KMZ and the settings as items of a
//! wear-levelled, power-fail-safe key-value log on NOR flash ([`sequential_storage`]'s map).
//!
//! Every write appends an item (header CRC + data CRC) to the open page; pages are used in turn,
//! so an hourly KMZ update writes ~40 bytes instead of erasing a slot, and each page is erased
//! once per lap of the whole region (wear levelling). Power lost in the middle of a write leaves
//! the previous value of that key in force: a torn item fails its CRC (a torn double word reads
//! as zeros, see [`crate::l4flash`]) and is skipped; the map repairs the page on the next write.
//!
//! The KMZ item carries the id of the model it belongs to, so λ_KMZ of an old model is never
//! applied to a new one.
//!
//! The store's scratch buffer (every item passes through it, so it holds the largest: a blob)
//! doubles as the upload buffer: a blob is either being received or being written, never both.
//! Between store operations the caller may keep bytes in [`Store::buffer`]; every operation
//! overwrites them. The model is therefore stored from its decoded form
//! ([`Store::save_model_with`] encodes it into the scratch, again after every page migration
//! that reused the scratch), not from the received bytes.

use core::fmt;
use embedded_storage_async::nor_flash::NorFlash;
use nanocal_model::{blob, MAX_AXES};
use sequential_storage::cache::key_pointers::ArrayKeyPointers;
use sequential_storage::cache::page_pointers::ArrayPagePointers;
use sequential_storage::cache::page_states::ArrayPageStates;
use sequential_storage::cache::Cache;
use sequential_storage::map::{MapConfig, MapStorage, SerializationError, Value};

/// Most erase units a store may have (the boards' have 8: 64 KiB in 8 KiB units).
pub const MAX_PAGES: usize = 32;

/// The map's cache: page states, page pointers, and where the newest item of each of the three
/// keys is. Without the key pointers, freeing a page costs a scan of the whole store per item
/// on that page (sequential-storage's `migrate_items` looks up the newest item of each key):
/// on a store whose free space KMZ updates had used up, the next upload kept the CPU busy for
/// more than the watchdog's 2 s and the board reset in the middle of the write — at every
/// attempt (tests/e2e_stm32_power_cut.rs). With them it is a lookup. ~330 bytes of RAM.
type MapCache =
    Cache<ArrayPageStates<MAX_PAGES>, ArrayPagePointers<MAX_PAGES>, ArrayKeyPointers<u8, 3>, u8>;

/// A value produced by an encoder straight into the map's data buffer (possibly several times:
/// a page migration reuses the buffer before the item is written).
struct Encoded<F: Fn(&mut [u8]) -> Option<usize>>(F);

impl<'a, F: Fn(&mut [u8]) -> Option<usize>> Value<'a> for Encoded<F> {
    fn serialize_into(&self, buffer: &mut [u8]) -> Result<usize, SerializationError> {
        (self.0)(buffer).ok_or(SerializationError::InvalidData)
    }
    fn deserialize_from(_: &'a [u8]) -> Result<(Self, usize), SerializationError> {
        // only ever written; items are read back as bytes
        Err(SerializationError::InvalidFormat)
    }
}

/// Item keys.
pub mod key {
    /// The model blob.
    pub const MODEL: u8 = 1;
    /// λ_KMZ of the model: model id u32, λ_KMZ f64 × 3.
    pub const KMZ: u8 = 2;
    /// Settings (the layout of `nanocal_interface::settings`).
    pub const SETTINGS: u8 = 3;
}

/// Scratch the store needs: the largest item (a blob) plus key and header, rounded up.
pub const SCRATCH: usize = blob::MAX_BLOB_LEN + 32;

/// KMZ item length.
pub const KMZ_LEN: usize = 4 + 8 * MAX_AXES;

/// Store failures.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum StoreError {
    /// The flash failed (erase, program) or the power went.
    Flash,
    /// The store is full (every page holds live items).
    Full,
    /// Flash state the map could not repair.
    Corrupted,
    /// An item was larger than the caller's buffer.
    TooLarge,
}

impl fmt::Display for StoreError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            StoreError::Flash => "flash erase/program failed",
            StoreError::Full => "store full",
            StoreError::Corrupted => "store corrupted beyond repair",
            StoreError::TooLarge => "stored item larger than the buffer",
        })
    }
}

fn err<E>(e: sequential_storage::Error<E>) -> StoreError {
    match e {
        sequential_storage::Error::Storage { .. } => StoreError::Flash,
        sequential_storage::Error::FullStorage => StoreError::Full,
        sequential_storage::Error::Corrupted { .. } => StoreError::Corrupted,
        sequential_storage::Error::BufferTooSmall(_) | sequential_storage::Error::BufferTooBig => {
            StoreError::TooLarge
        }
        _ => StoreError::Corrupted,
    }
}

/// The store over `flash` (the whole of it: erase-unit aligned).
pub struct Store<F: NorFlash> {
    map: MapStorage<u8, F, MapCache>,
    scratch: [u8; SCRATCH],
}

impl<F: NorFlash> Store<F> {
    /// A store over the whole of `flash`.
    ///
    /// # Panics
    /// When `flash` has more than [`MAX_PAGES`] erase units (a board's configuration error).
    pub fn new(flash: F) -> Self {
        let pages = flash.capacity() / F::ERASE_SIZE;
        assert!(
            pages <= MAX_PAGES,
            "a store of {pages} erase units: at most {MAX_PAGES}"
        );
        let end = (pages * F::ERASE_SIZE) as u32;
        let cache = MapCache::new(
            ArrayPageStates::new(),
            ArrayPagePointers::new(),
            ArrayKeyPointers::new(),
        );
        Self {
            map: MapStorage::new(flash, MapConfig::new(0..end), cache),
            scratch: [0; SCRATCH],
        }
    }

    /// The flash (e.g. for statistics).
    pub fn flash(&mut self) -> &mut F {
        self.map.flash()
    }

    /// The scratch buffer ([`SCRATCH`] bytes), free for the caller between store operations
    /// (e.g. an upload being received); every load or save overwrites it.
    pub fn buffer(&mut self) -> &mut [u8] {
        &mut self.scratch
    }

    async fn fetch(&mut self, k: u8, out: &mut [u8]) -> Result<Option<usize>, StoreError> {
        let v: Option<&[u8]> = self
            .map
            .fetch_item(&mut self.scratch, &k)
            .await
            .map_err(err)?;
        match v {
            None => Ok(None),
            Some(v) if v.len() > out.len() => Err(StoreError::TooLarge),
            Some(v) => {
                out[..v.len()].copy_from_slice(v);
                Ok(Some(v.len()))
            }
        }
    }

    async fn put(&mut self, k: u8, v: &[u8]) -> Result<(), StoreError> {
        self.map
            .store_item(&mut self.scratch, &k, &v)
            .await
            .map_err(err)
    }

    /// The stored model blob into `out`; its length.
    pub async fn load_model(&mut self, out: &mut [u8]) -> Result<Option<usize>, StoreError> {
        self.fetch(key::MODEL, out).await
    }

    /// The stored model blob, handed to `f` where it lies (in the scratch, no copy).
    pub async fn load_model_with<R>(
        &mut self,
        f: impl FnOnce(&[u8]) -> R,
    ) -> Result<Option<R>, StoreError> {
        let k = key::MODEL;
        let v: Option<&[u8]> = self
            .map
            .fetch_item(&mut self.scratch, &k)
            .await
            .map_err(err)?;
        Ok(v.map(f))
    }

    /// Store the model blob that `encode` writes into the buffer it is given (returning its
    /// length, `None` if it cannot): called once or, when the store must first migrate items
    /// through the scratch, again after that.
    pub async fn save_model_with(
        &mut self,
        encode: impl Fn(&mut [u8]) -> Option<usize>,
    ) -> Result<(), StoreError> {
        let k = key::MODEL;
        self.map
            .store_item(&mut self.scratch, &k, &Encoded(encode))
            .await
            .map_err(err)
    }

    /// Store a model blob (its KMZ item, if any, no longer matches its id and is ignored).
    pub async fn save_model(&mut self, blob_bytes: &[u8]) -> Result<(), StoreError> {
        self.put(key::MODEL, blob_bytes).await
    }

    /// λ_KMZ stored for model `model_id`.
    pub async fn load_kmz(&mut self, model_id: u32) -> Result<Option<[f64; MAX_AXES]>, StoreError> {
        let mut b = [0u8; KMZ_LEN];
        match self.fetch(key::KMZ, &mut b).await? {
            Some(KMZ_LEN) if u32::from_le_bytes([b[0], b[1], b[2], b[3]]) == model_id => {
                let mut k = [0.0; MAX_AXES];
                for (a, v) in k.iter_mut().enumerate() {
                    let mut f = [0u8; 8];
                    f.copy_from_slice(&b[4 + 8 * a..12 + 8 * a]);
                    *v = f64::from_le_bytes(f);
                }
                Ok(Some(k))
            }
            _ => Ok(None),
        }
    }

    /// Store λ_KMZ for model `model_id`.
    pub async fn save_kmz(
        &mut self,
        model_id: u32,
        kmz_um: &[f64; MAX_AXES],
    ) -> Result<(), StoreError> {
        let mut b = [0u8; KMZ_LEN];
        b[..4].copy_from_slice(&model_id.to_le_bytes());
        for (a, v) in kmz_um.iter().enumerate() {
            b[4 + 8 * a..12 + 8 * a].copy_from_slice(&v.to_le_bytes());
        }
        self.put(key::KMZ, &b).await
    }

    /// The stored settings bytes.
    pub async fn load_settings(&mut self, out: &mut [u8]) -> Result<Option<usize>, StoreError> {
        self.fetch(key::SETTINGS, out).await
    }

    /// Store settings bytes.
    pub async fn save_settings(&mut self, bytes: &[u8]) -> Result<(), StoreError> {
        self.put(key::SETTINGS, bytes).await
    }
}
