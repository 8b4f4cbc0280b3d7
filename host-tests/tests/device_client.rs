//! The host's management client against a scripted device (issue 21, item 7): a device of
//! another protocol version is named as such before any of its bytes are misread; the model's
//! content hash is shown with its id; an upload whose commit reports another blob CRC than the
//! blob's is an error.

use nanocal::device::{format_status, Client, DeviceError};
use nanocal::papers::published::published_1dof;
use nanocal_interface::identity::ResetCause;
use nanocal_interface::mgmt::{self, Decoder, Hello, Kind, Reply, Request, Writer};
use nanocal_interface::status::{Flags, Status};
use nanocal_model::blob;
use std::collections::VecDeque;
use std::io::{Read, Write};
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// A device that answers each request frame at once: `HELLO` with `protocol` (and protocol
/// 4's HELLO layout is the same as 5's), `STATUS` with a model, uploads committed with
/// `commit_crc`. `kinds` records the kinds of the requests it received.
struct FakeDevice {
    protocol: u16,
    commit_crc: u32,
    dec: Decoder,
    out: VecDeque<u8>,
    kinds: Arc<Mutex<Vec<u8>>>,
}

impl FakeDevice {
    fn reply(&self, k: u8, payload: &[u8]) -> Reply {
        match Request::decode(k, payload).expect("a well-formed request") {
            Request::Hello => {
                let mut firmware = nanocal_interface::heapless::String::new();
                firmware.push_str("0.0.9").unwrap();
                Reply::Hello(Hello {
                    protocol: self.protocol,
                    blob_format: blob::FORMAT_VERSION,
                    max_chunk: mgmt::MAX_CHUNK as u16,
                    firmware,
                    uid: [7; 12],
                    reset_cause: ResetCause::PowerOn,
                    reset_site: Default::default(),
                })
            }
            Request::Status => Reply::Status(Status {
                flags: Flags::MODEL,
                model_id: 0x0003_0001,
                model_crc32: 0x89AB_CDEF,
                ..Default::default()
            }),
            Request::UploadBegin { .. } => Reply::UploadBegin,
            Request::UploadChunk { offset, bytes } => Reply::UploadChunk {
                received: offset + bytes.len() as u32,
            },
            Request::UploadCommit => Reply::UploadCommit {
                model_id: 0x0001_0001,
                model_crc32: self.commit_crc,
                uploads_accepted: 1,
            },
            other => panic!("not scripted: {other:?}"),
        }
    }
}

impl Write for FakeDevice {
    fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
        for &x in b {
            let mut ev = self.dec.feed(x, 0);
            while let Some(e) = ev {
                e.expect("the client sends good frames");
                let f = self.dec.frame();
                let (k, seq) = (f.kind, f.seq);
                self.kinds.lock().unwrap().push(k);
                let reply = self.reply(k, f.payload);
                let mut frame = [0u8; mgmt::MAX_FRAME];
                let mut w = Writer::new(&mut frame[mgmt::PAYLOAD_AT..][..mgmt::MAX_PAYLOAD]);
                reply.encode(&mut w).unwrap();
                let len = w.len();
                let n = mgmt::seal(k | mgmt::REPLY, seq, len, &mut frame).unwrap();
                self.out.extend(&frame[..n]);
                ev = self.dec.next(0);
            }
        }
        Ok(b.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

impl Read for FakeDevice {
    fn read(&mut self, b: &mut [u8]) -> std::io::Result<usize> {
        let n = b.len().min(self.out.len());
        if n == 0 {
            return Err(std::io::ErrorKind::WouldBlock.into());
        }
        for x in b.iter_mut().take(n) {
            *x = self.out.pop_front().unwrap();
        }
        Ok(n)
    }
}

fn client(protocol: u16, commit_crc: u32) -> (Client, Arc<Mutex<Vec<u8>>>) {
    let kinds = Arc::new(Mutex::new(vec![]));
    let dev = FakeDevice {
        protocol,
        commit_crc,
        dec: Decoder::new(),
        out: VecDeque::new(),
        kinds: kinds.clone(),
    };
    (
        Client::new(Box::new(dev), "fake", Duration::from_millis(500)),
        kinds,
    )
}

#[test]
fn a_device_of_another_protocol_version_is_named_before_its_status_is_read() {
    let (mut c, kinds) = client(4, 0);
    let e = c.status().unwrap_err();
    match &e {
        DeviceError::ProtocolVersion {
            device,
            host,
            firmware,
            ..
        } => {
            assert_eq!((*device, *host), (4, mgmt::PROTOCOL));
            assert_eq!(firmware.as_deref(), Some("0.0.9"));
        }
        other => panic!("{other:?}"),
    }
    let msg = e.to_string();
    assert!(
        msg.contains(&format!(
            "speaks management protocol 4 (firmware 0.0.9), this nanocal speaks {}",
            mgmt::PROTOCOL
        )),
        "{msg}"
    );
    assert_eq!(
        *kinds.lock().unwrap(),
        vec![Kind::Hello.code()],
        "nothing but HELLO went to the device"
    );
}

#[test]
fn the_status_shows_the_model_hash_with_its_id() {
    let (mut c, kinds) = client(mgmt::PROTOCOL, 0);
    let s = c.status().unwrap();
    assert_eq!((s.model_id, s.model_crc32), (0x0003_0001, 0x89AB_CDEF));
    assert!(format_status(&s).contains("model: 0x00030001  blob CRC 0x89abcdef"));
    assert_eq!(
        *kinds.lock().unwrap(),
        vec![Kind::Hello.code(), Kind::Status.code()]
    );
}

#[test]
fn an_upload_is_confirmed_by_the_blob_crc_the_device_stored() {
    let model = published_1dof().unwrap();
    let mut b = vec![0u8; blob::MAX_BLOB_LEN];
    let n = blob::encode(&model, &mut b).unwrap();
    b.truncate(n);
    let crc = blob::stored_crc(&b).unwrap();

    let (mut c, _) = client(mgmt::PROTOCOL, crc);
    let done = c.upload(&b).unwrap();
    assert_eq!(done.model_crc32, crc);

    let (mut c, _) = client(mgmt::PROTOCOL, crc ^ 1);
    match c.upload(&b) {
        Err(DeviceError::StoredOtherBlob { device, blob, .. }) => {
            assert_eq!((device, blob), (crc ^ 1, crc))
        }
        other => panic!("{other:?}"),
    }
}
