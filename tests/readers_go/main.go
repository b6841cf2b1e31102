// Command uv3dp-layers decodes a resin print file with the format packages of
// github.com/ezrec/uv3dp and prints, as one JSON object, what uv3dp reads from
// it: the bed size, exposure and bottom settings, metadata, previews and, per
// layer, the Z, the exposure and a SHA-256 of the decoded 8-bit image.
//
// It is a test tool for skelslice (an independent reader of the files skelslice
// writes), not part of the package.
//
//	uv3dp-layers FILE [PNGDIR]
//
// With PNGDIR, every decoded layer is also written there as NNNNNNNN.png.
//
// The uv3dp command line converts between formats through the Printable
// interface's LayerImage method; uv3dp's pws/pw0 reader implements its decoder
// as Print.Image instead (since uv3dp commit b2a539c), so its LayerImage is the
// embedded default, an empty image. This tool calls Image where a reader has it,
// so the layers come from uv3dp's own RLE decoders in every case, and reports
// which method it used.
package main

import (
	"crypto/sha256"
	"encoding/hex"
	"encoding/json"
	"fmt"
	"image"
	"image/png"
	"os"
	"path/filepath"

	"github.com/ezrec/uv3dp"
	_ "github.com/ezrec/uv3dp/cbddlp"
	_ "github.com/ezrec/uv3dp/ctb"
	_ "github.com/ezrec/uv3dp/pws"
	_ "github.com/ezrec/uv3dp/sl1"
	_ "github.com/ezrec/uv3dp/uvj"
)

type layerReport struct {
	Z        float32        `json:"z"`
	Exposure uv3dp.Exposure `json:"exposure"`
	Width    int            `json:"width"`
	Height   int            `json:"height"`
	Lit      int            `json:"lit"`
	GreySum  uint64         `json:"grey_sum"`
	Sha256   string         `json:"sha256"`
}

type previewReport struct {
	Width  int `json:"width"`
	Height int `json:"height"`
}

type report struct {
	Size     uv3dp.Size               `json:"size"`
	Exposure uv3dp.Exposure           `json:"exposure"`
	Bottom   uv3dp.Bottom             `json:"bottom"`
	Metadata map[string]interface{}   `json:"metadata"`
	Previews map[string]previewReport `json:"previews"`
	Decoder  string                   `json:"decoder"`
	Layers   []layerReport            `json:"layers"`
}

type imager interface {
	Image(index int) *image.Gray
}

func fail(msg string) {
	out, _ := json.Marshal(map[string]string{"error": msg})
	fmt.Println(string(out))
	os.Exit(1)
}

func layerImage(p uv3dp.Printable, n int) *image.Gray {
	if im, ok := p.(imager); ok {
		return im.Image(n)
	}
	return p.LayerImage(n)
}

func describe(gray *image.Gray) layerReport {
	b := gray.Bounds()
	w, h := b.Dx(), b.Dy()
	sum := sha256.New()
	rep := layerReport{Width: w, Height: h}
	for y := 0; y < h; y++ {
		row := gray.Pix[y*gray.Stride : y*gray.Stride+w]
		sum.Write(row)
		for _, v := range row {
			if v != 0 {
				rep.Lit++
			}
			rep.GreySum += uint64(v)
		}
	}
	rep.Sha256 = hex.EncodeToString(sum.Sum(nil))
	return rep
}

func run(path, pngDir string) (rep report) {
	format, err := uv3dp.NewFormat(path, nil)
	if err != nil {
		fail(err.Error())
	}
	printable, err := format.Printable()
	if err != nil {
		fail(err.Error())
	}
	rep.Size = printable.Size()
	rep.Exposure = printable.Exposure()
	rep.Bottom = printable.Bottom()
	rep.Metadata = map[string]interface{}{}
	for _, key := range printable.MetadataKeys() {
		rep.Metadata[key], _ = printable.Metadata(key)
	}
	rep.Previews = map[string]previewReport{}
	for name, kind := range map[string]uv3dp.PreviewType{"tiny": uv3dp.PreviewTypeTiny, "huge": uv3dp.PreviewTypeHuge} {
		if pic, ok := printable.Preview(kind); ok && pic != nil {
			rep.Previews[name] = previewReport{pic.Bounds().Dx(), pic.Bounds().Dy()}
		}
	}
	rep.Decoder = "LayerImage"
	if _, ok := printable.(imager); ok {
		rep.Decoder = "Image"
	}
	for n := 0; n < rep.Size.Layers; n++ {
		gray := layerImage(printable, n)
		layer := describe(gray)
		layer.Z = printable.LayerZ(n)
		layer.Exposure = printable.LayerExposure(n)
		rep.Layers = append(rep.Layers, layer)
		if pngDir != "" {
			f, err := os.Create(filepath.Join(pngDir, fmt.Sprintf("%08d.png", n)))
			if err != nil {
				fail(err.Error())
			}
			if err := png.Encode(f, gray); err != nil {
				fail(err.Error())
			}
			f.Close()
		}
	}
	return
}

func main() {
	if len(os.Args) < 2 || len(os.Args) > 3 {
		fmt.Fprintln(os.Stderr, "usage: uv3dp-layers FILE [PNGDIR]")
		os.Exit(2)
	}
	pngDir := ""
	if len(os.Args) == 3 {
		pngDir = os.Args[2]
	}
	// uv3dp's decoders panic on corrupt layer data: report that as a rejection.
	defer func() {
		if r := recover(); r != nil {
			fail(fmt.Sprint("uv3dp panicked: ", r))
		}
	}()
	rep := run(os.Args[1], pngDir)
	out, err := json.Marshal(rep)
	if err != nil {
		fail(err.Error())
	}
	fmt.Println(string(out))
}
